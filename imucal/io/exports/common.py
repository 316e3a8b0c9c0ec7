"""What every export needs: the calibration file read back, its units, one segment chosen, and
the arithmetic of unit changes.

The model exported is imucal's (method.md M2, M4): ``x = T K (x_raw - b)`` per sensor and
segment, ``x_raw`` in the raw unit the calibration was fitted on (g, m/s^2 or counts for the
accelerometer; rad/s or counts for the gyroscope, deg/s input having been converted to rad/s
on load), ``x`` in the calibrated unit (g or m/s^2; rad/s).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from imucal.errors import ImucalError
from imucal.io.calibration_file import load_calibration
from imucal.io.exports.mag import MagModel, read_mag
from imucal.io.exports.sections import Extras, read_extras
from imucal.models import SensorModel
from imucal.session import STANDARD_GRAVITY
from imucal.stages.apply import Calibration, SegmentModels

# m/s^2 per unit of an accelerometer signal (None: no physical unit)
ACC_SI = {"g": STANDARD_GRAVITY, "m/s^2": 1.0, "counts": None}
RAD = math.pi / 180.0  # rad/s per deg/s


@dataclass(frozen=True)
class ExportInput:
    """A calibration file read for export: the models, units, noise figures, provenance."""

    path: Path
    calibration: Calibration
    noise: dict | None  # the calib.json ``noise`` key (or a noise file's figures)
    source: dict  # the calib.json ``source`` key
    magnetometer: MagModel | None = None  # its ``magnetometer`` section, when calibrated
    # its other triads and temperature models (method.md §11, §12); None: it has neither
    extras: Extras | None = None
    quality: dict | None = None  # its ``quality`` key (the C runtime's stored still-norm error)

    @property
    def has_gyro(self) -> bool:
        return all(s.gyro is not None for s in self.calibration.segments)

    def segment(self, index: int | None, fmt: str) -> tuple[int, SegmentModels]:
        """The one segment a single-model format takes: ``index`` its number from 1, as
        ``imucal calibrate`` prints it (:attr:`imucal.result.Segment.number`). Several segments
        and no index is refused with the list of them and their times: a one-model file made
        from the wrong segment would be flashed without a word."""
        segs = self.calibration.segments
        if index is None:
            if len(segs) > 1:
                raise ImucalError(f"the calibration has {len(segs)} segments and {fmt} holds "
                                  f"one model; choose one with --segment N: "
                                  f"{segment_list(segs)} (the c, json and yaml exports keep "
                                  "them all)", source=str(self.path), field="segments")
            index = 1
        if not 1 <= index <= len(segs):
            raise ImucalError(f"segment {index} does not exist; the segments are "
                              f"{segment_list(segs)}", source=str(self.path), field="segments")
        return index, segs[index - 1]

    def header_lines(self) -> list[str]:
        """Provenance for a comment block at the top of an exported file."""
        cal = self.calibration
        src = self.source or {}
        lines = [f"written by imucal from {self.path.name}"]
        if src.get("file"):
            lines.append(f"calibrated on {src['file']} (sha256 {str(src.get('sha256'))[:16]}...)")
        lines.append(f"raw units: accelerometer {cal.acc_unit_raw}, gyroscope "
                     f"{cal.gyro_unit_raw or 'none'}; calibrated: accelerometer {cal.acc_unit} "
                     f"(|g| = {cal.g:g}), gyroscope rad/s")
        return lines


def segment_list(segments: tuple[SegmentModels, ...]) -> str:
    """"1 (0.0-90.2 s), 2 (95.1-180.0 s)": each segment's number and its times, on the
    calibration session's clock."""
    return ", ".join(f"{i} ({s.t_start:.1f}-{s.t_end:.1f} s)"
                     for i, s in enumerate(segments, start=1))


@dataclass
class Exported:
    """Files to write (path, text) and what the conversion kept or lost, in words."""

    files: list[tuple[Path, str]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def read_export_input(path: str | Path, noise_path: str | Path | None = None) -> ExportInput:
    """Read a calibration file (and optionally the noise figures of ``imucal noise --out``)."""
    path = Path(path)
    cal = load_calibration(path)  # checks the format; raises ImucalError
    data = json.loads(path.read_text(encoding="utf-8"))
    noise = data.get("noise")
    if noise_path is not None:
        noise = _read_noise(Path(noise_path))
    return ExportInput(path=path, calibration=cal, noise=noise, source=data.get("source") or {},
                       magnetometer=read_mag(data, path), extras=read_extras(data, path, cal),
                       quality=data.get("quality"))


def _read_noise(path: Path) -> dict:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ImucalError("file not found", source=str(path)) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ImucalError(f"not a readable JSON file ({e.__class__.__name__})",
                          source=str(path)) from None
    if isinstance(data, dict) and data.get("still") is False:
        raise ImucalError("the recording was not still: its figures measure the motion, not "
                          "the noise", source=str(path), field="noise")
    noise = data.get("noise", data) if isinstance(data, dict) else None
    if not isinstance(noise, dict) or not ({"accelerometer", "gyroscope"} & set(noise)):
        raise ImucalError("expected the noise figures of 'imucal noise --out' (keys "
                          "accelerometer, gyroscope)", source=str(path), field="noise")
    return noise


def si_acc_factors(inp: ExportInput, fmt: str, cal: Calibration | None = None
                   ) -> tuple[float, float]:
    """(m/s^2 per raw unit, m/s^2 per calibrated unit) of ``cal`` (the file's calibration, or
    one of its other triads'); raw counts have no SI factor."""
    cal = cal if cal is not None else inp.calibration
    c_in = ACC_SI.get(cal.acc_unit_raw)
    if c_in is None:
        raise ImucalError(f"{fmt} takes the accelerometer in m/s^2 as its driver reports it, and "
                          "this calibration was fitted on raw counts (the driver's counts-to-m/s^2 "
                          "factor is unknown to imucal); calibrate the driver's output in m/s^2 "
                          "or g", source=str(inp.path), field="units")
    c_out = ACC_SI[cal.acc_unit]
    assert c_out is not None
    return c_in, c_out


def require_gyro_rad(inp: ExportInput, fmt: str, cal: Calibration | None = None) -> None:
    cal = cal if cal is not None else inp.calibration
    if all(s.gyro is not None for s in cal.segments) and cal.gyro_unit_raw == "counts":
        raise ImucalError(f"{fmt} takes the gyroscope in rad/s, and this calibration was fitted "
                          "on raw counts; calibrate the driver's output in rad/s or deg/s",
                          source=str(inp.path), field="units")


def piece_models(segments: tuple[SegmentModels, ...], which: str
                 ) -> list[tuple[str, float, float, SensorModel | None]]:
    """The pieces of time :meth:`Calibration.apply` uses, in order: ("segment", t_start,
    t_end, model) for segment i over the closed [t_start, t_end], then ("between", t_end_i,
    t_start_i+1, mean) over the open gap to the next segment with the parameter-wise mean of
    the two (method.md §2); no gap piece where the segments touch."""
    out: list[tuple[str, float, float, SensorModel | None]] = []
    for i, s in enumerate(segments):
        out.append(("segment", s.t_start, s.t_end, getattr(s, which)))
        if i + 1 < len(segments) and segments[i + 1].t_start > s.t_end:
            a, b = getattr(s, which), getattr(segments[i + 1], which)
            mean = None if a is None or b is None else SensorModel.mean(a, b)
            out.append(("between", s.t_end, segments[i + 1].t_start, mean))
    return out


def fibonacci_sphere(n: int = 2000) -> np.ndarray:
    """``n`` unit vectors spread evenly over the sphere (golden-angle spiral)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - z * z)
    phi = i * math.pi * (3.0 - math.sqrt(5.0))
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def fmt_num(x: float) -> str:
    """Shortest text that reads back to the same double."""
    return repr(float(x))
