"""A calibration that knows its units, its model and its format, and cannot be misapplied.

``Calibration.apply`` turns a raw session into calibrated signals: each segment's models over
its own time span, the parameter-wise mean of the two neighbours' between two segments
(method.md §2). The first segment extends back to the start of time and the last to its end,
so a one-segment calibration applies to any later recording of the same device.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from imucal.errors import ImucalError
from imucal.models import SensorModel
from imucal.session import Session


@dataclass(frozen=True)
class MagModel:
    """The magnetometer's M8 (stages/mag.py) as applying it needs: ``m = R_am M (m_raw - b)``
    in the raw unit ``unit`` (None: unstated), over the whole session; ``field`` the local
    field's norm F in that unit (None: a file that does not state it)."""

    M: np.ndarray
    b: np.ndarray
    R_am: np.ndarray  # the identity where the rotation was not estimated
    unit: str | None = None
    field: float | None = None

    def apply(self, raw: np.ndarray) -> np.ndarray:
        return (np.asarray(raw, float) - self.b) @ (self.R_am @ self.M).T


@dataclass(frozen=True)
class SegmentModels:
    t_start: float
    t_end: float
    acc: SensorModel
    gyro: SensorModel | None


@dataclass(frozen=True)
class Calibration:
    segments: tuple[SegmentModels, ...]
    acc_unit_raw: str  # "g", "m/s^2" or "counts"
    acc_unit: str  # unit of the calibrated accelerometer ("g" or "m/s^2")
    g: float  # |g| in acc_unit
    gyro_unit_raw: str | None  # "rad/s" or "counts" (deg/s input is converted on load)
    mag: MagModel | None = None  # the magnetometer, when the calibration has one

    def check_units(self, session: Session) -> None:
        """Refuse a session in other units than the calibration was fitted on (style.md)."""
        if session.acc_unit != self.acc_unit_raw:
            raise ImucalError(f"the calibration was fitted on an accelerometer in "
                              f"{self.acc_unit_raw}, this session is in {session.acc_unit}",
                              source=session.source, field="accelerometer unit")
        if session.has_gyro and self.gyro_unit_raw and session.gyro_unit != self.gyro_unit_raw:
            raise ImucalError(f"the calibration was fitted on a gyroscope in "
                              f"{self.gyro_unit_raw}, this session is in {session.gyro_unit}",
                              source=session.source, field="gyroscope unit")

    def to_dict(self) -> dict:
        """What applying this calibration needs, as plain JSON values: the units and each
        segment's models (M2, M4). :meth:`from_dict` reads it back exactly."""
        return {
            "units": {"accelerometer_raw": self.acc_unit_raw, "accelerometer": self.acc_unit,
                      "g": float(self.g), "gyroscope_raw": self.gyro_unit_raw,
                      "gyroscope": "rad/s" if self.gyro_unit_raw else None, "time": "s"},
            "segments": [{"t_start": float(seg.t_start), "t_end": float(seg.t_end),
                          "accelerometer": model_dict(seg.acc),
                          "gyroscope": None if seg.gyro is None else model_dict(seg.gyro)}
                         for seg in self.segments],
        } | ({} if self.mag is None else {"magnetometer": {
            "calibrated": True, "unit": self.mag.unit, "M": self.mag.M.tolist(),
            "b": self.mag.b.tolist(), "R_am": self.mag.R_am.tolist()}
            | ({} if self.mag.field is None else {"field": float(self.mag.field)})})

    @classmethod
    def from_dict(cls, data: dict) -> Calibration:
        """The inverse of :meth:`to_dict` (extra keys, such as a calibration file's standard
        errors and quality figures, are ignored). Every parameter is checked, so that a
        hand-edited or damaged calibration is one clear error and never one that silently
        zeroes or scrambles a signal: T finite and invertible, K finite and non-zero, b finite
        (M2, M4); g finite and > 0; the units known; the segments in time order. Raises
        :class:`ImucalError` naming the field."""
        field = "units"
        try:
            units = data["units"]
            raw = _unit(units, "accelerometer_raw", ACC_UNITS_RAW)
            out = _unit(units, "accelerometer", ACC_UNITS)
            gyro_raw = _unit(units, "gyroscope_raw", GYRO_UNITS_RAW, optional=True)
            field = "units.g"
            g = _number(units["g"], "g")
            if not g > 0:
                raise ValueError(f"g must be > 0, got {g:g}")
            segments: list[SegmentModels] = []
            for i, seg in enumerate(data["segments"]):
                field = f"segments[{i}]"
                t0, t1 = _number(seg["t_start"], "t_start"), _number(seg["t_end"], "t_end")
                if t1 < t0 or (segments and t0 < segments[-1].t_end):
                    raise ValueError("the segments' t_start and t_end are not in time order")
                field = f"segments[{i}].accelerometer"
                acc = _model(seg["accelerometer"])
                field = f"segments[{i}].gyroscope"
                gyro = _model(seg["gyroscope"]) if seg.get("gyroscope") else None
                segments.append(SegmentModels(t_start=t0, t_end=t1, acc=acc, gyro=gyro))
            if not segments:
                field = "segments"
                raise ValueError("no segments")
            field = "magnetometer"
            mag = _mag_model(data.get("magnetometer"))
        except (KeyError, TypeError, ValueError, IndexError, AttributeError) as e:
            what = f"missing {e}" if isinstance(e, KeyError) else str(e)
            raise ImucalError(f"malformed calibration: {what}", field=field) from None
        return cls(segments=tuple(segments), acc_unit_raw=raw, acc_unit=out, g=g,
                   gyro_unit_raw=gyro_raw, mag=mag)

    def apply(self, session: Session) -> CalibratedSignals:
        self.check_units(session)
        acc = _apply_piecewise(session.acc, session.t_acc, self.segments, "acc")
        gyro = None
        if self.applies_gyro(session):
            gyro = _apply_piecewise(session.gyro, session.t_gyro, self.segments, "gyro")
        t_mag = mag = None
        stream = session.magnetometer
        if self.mag is not None and stream is not None:
            if None not in (self.mag.unit, stream.unit) and self.mag.unit != stream.unit:
                raise ImucalError(f"the calibration's magnetometer was fitted in "
                                  f"{self.mag.unit}, this session's is in {stream.unit}",
                                  source=session.source, field="magnetometer unit")
            t_mag, mag = stream.t, self.mag.apply(stream.values)
        return CalibratedSignals(t_acc=session.t_acc, acc=acc, t_gyro=session.t_gyro,
                                 gyro=gyro, acc_unit=self.acc_unit, t_mag=t_mag, mag=mag)

    def applies_gyro(self, session: Session) -> bool:
        """Does :meth:`apply` calibrate this session's gyroscope (a model in every segment)?"""
        return session.has_gyro and all(s.gyro is not None for s in self.segments)

    def rows(self, session: Session, which: str, lo: int, hi: int) -> np.ndarray:
        """Calibrated rows ``[lo, hi)`` of the accelerometer (``which="acc"``) or the
        gyroscope (``"gyro"``): bit for bit ``self.apply(session).acc[lo:hi]`` (or ``.gyro``),
        without the signal-sized array, for the stages that read the calibrated signals a block
        or a turn at a time (quality, guide, noise)."""
        if which == "acc":
            return _apply_rows(session.acc, session.t_acc, self.segments, "acc", lo, hi)
        if not self.applies_gyro(session):
            raise ValueError("no calibrated gyroscope in this calibration or session")
        return _apply_rows(session.gyro, session.t_gyro, self.segments, "gyro", lo, hi)


@dataclass(frozen=True)
class CalibratedSignals:
    t_acc: np.ndarray
    acc: np.ndarray
    t_gyro: np.ndarray | None
    gyro: np.ndarray | None  # rad/s
    acc_unit: str
    t_mag: np.ndarray | None = None  # the magnetometer's own clock, s
    mag: np.ndarray | None = None  # M8 applied: the raw unit, the accelerometer's frame
    # More columns on the accelerometer's rows (the other triads a2x…, g2x…, the combined
    # acx…, temp: stages/apply_triads.py), in the order written; empty for one triad.
    columns: dict[str, np.ndarray] = field(default_factory=dict)

    def mag_normalised(self, cal: Calibration, source: str) -> CalibratedSignals:
        """The same signals with the magnetometer divided by the calibration's field F
        (``|m| = 1`` where the field is the one calibrated: ``--mag-unit norm``)."""
        if self.mag is None:
            return self
        if cal.mag is None or cal.mag.field is None:
            raise ImucalError("the calibration states no field norm to normalise the "
                              "magnetometer by (expected its magnetometer section's field)",
                              source=source, field="magnetometer field")
        return replace(self, mag=self.mag / cal.mag.field)

    @property
    def acc_norm(self) -> np.ndarray:
        return np.linalg.norm(self.acc, axis=1)

    @property
    def gyro_norm(self) -> np.ndarray | None:
        return None if self.gyro is None else np.linalg.norm(self.gyro, axis=1)


def segment_pieces(t: np.ndarray, segments: tuple[SegmentModels, ...],
            which: str) -> list[tuple[int, int, SensorModel]]:
    """``[lo, hi)`` sample ranges of ``t`` and the model applied to each: segment i owns
    ``[t_start_i, t_end_i]``, the gap between i and i + 1 takes the mean of their models."""
    n_seg = len(segments)
    models = [getattr(s, which) for s in segments]
    starts = [-np.inf] + [s.t_start for s in segments[1:]]
    ends = [s.t_end for s in segments[:-1]] + [np.inf]
    out = []
    for i in range(n_seg):
        lo = int(np.searchsorted(t, starts[i], side="left"))
        hi = int(np.searchsorted(t, ends[i], side="right"))
        out.append((lo, hi, models[i]))
        if i + 1 < n_seg:
            g_hi = int(np.searchsorted(t, starts[i + 1], side="left"))
            if g_hi > hi:
                out.append((hi, g_hi, SensorModel.mean(models[i], models[i + 1])))
    return out


def _apply_piecewise(raw: np.ndarray, t: np.ndarray, segments: tuple[SegmentModels, ...],
                     which: str) -> np.ndarray:
    """Each sample through its segment's model, or the mean of the neighbours' in a gap.

    Vectorised: the samples of one piece are a contiguous slice found by searchsorted, so the
    work is one matrix product per piece, not per sample.
    """
    out = np.empty(raw.shape, dtype=np.float64)
    for lo, hi, model in segment_pieces(t, segments, which):
        _apply_into(model, raw[lo:hi], out[lo:hi])
    return out


def _apply_rows(raw: np.ndarray, t: np.ndarray, segments: tuple[SegmentModels, ...],
                which: str, lo: int, hi: int) -> np.ndarray:
    """Rows ``[lo, hi)`` of :func:`_apply_piecewise`, the same to the bit: each piece is
    computed over the chunks of the whole's grid (``CHUNK_ROWS`` from the piece's start) that
    meet ``[lo, hi)``, so every matrix product is the one the whole makes (the same rows, the
    same shapes) and none depends on how BLAS treats a shorter or shifted block."""
    pieces = [(p0, p1, m) for p0, p1, m in segment_pieces(t, segments, which)
              if max(p0, lo) < min(p1, hi)]
    out = None
    if len(pieces) != 1 or not (pieces[0][0] <= lo and hi <= pieces[0][1]):
        out = np.empty((max(hi - lo, 0),) + raw.shape[1:], dtype=np.float64)
    for p0, p1, model in pieces:
        a, b = max(p0, lo), min(p1, hi)
        g0 = p0 + (a - p0) // CHUNK_ROWS * CHUNK_ROWS
        g1 = min(p1, p0 + -(-(b - p0) // CHUNK_ROWS) * CHUNK_ROWS)
        tmp = np.empty((g1 - g0,) + raw.shape[1:], dtype=np.float64)
        _apply_into(model, raw[g0:g1], tmp)
        if out is None:  # one piece holds [lo, hi): its rows, no second copy
            return tmp[a - g0:b - g0]
        out[a - lo:b - lo] = tmp[a - g0:b - g0]
    return np.empty((0,) + raw.shape[1:]) if out is None else out


CHUNK_ROWS = 1 << 16


def _apply_into(model: SensorModel, raw: np.ndarray, out: np.ndarray) -> None:
    """``out = model.apply(raw)`` (M2/M4, ``T K (raw - b)``), a cache-sized chunk at a time.

    The same arithmetic as :meth:`SensorModel.apply`, without its two signal-sized temporaries:
    at 1 kHz for 90 minutes each is 130 MB of fresh pages, and the page faults cost more than
    the arithmetic and made this stage's time per sample vary 3x between runs (bench/).
    """
    M = model.matrix.T
    tmp = np.empty((min(CHUNK_ROWS, len(raw)), raw.shape[1]))
    for lo in range(0, len(raw), CHUNK_ROWS):
        hi = min(lo + CHUNK_ROWS, len(raw))
        d = tmp[:hi - lo]
        np.subtract(raw[lo:hi], model.b, out=d)
        np.matmul(d, M, out=out[lo:hi])


ACC_UNITS_RAW = ("g", "m/s^2", "counts")
ACC_UNITS = ("g", "m/s^2")
GYRO_UNITS_RAW = ("rad/s", "deg/s", "counts")


def model_dict(model: SensorModel) -> dict:
    """One sensor's T, K, b (M2, M4) as JSON lists."""
    return {"T": np.asarray(model.T, float).tolist(), "K": np.asarray(model.K, float).tolist(),
            "b": np.asarray(model.b, float).tolist()}


def _unit(units: dict, key: str, known: tuple[str, ...], optional: bool = False) -> str | None:
    value = units.get(key) if optional else units[key]
    if (value is None and optional) or value in known:
        return value
    raise ValueError(f"{key} {value!r} is not one of {', '.join(known)}")


def _mag_model(d: Any) -> MagModel | None:
    """The magnetometer section's M, b, R_am (M8), or None where the file has none or says
    it was not calibrated; refused unless M is finite and invertible, b finite and R_am a
    rotation (or null: none estimated)."""
    if d is None or (isinstance(d, dict) and d.get("calibrated") is False):
        return None
    arrays = {}
    for key, shape in (("M", (3, 3)), ("b", (3,)), ("R_am", (3, 3))):
        raw = d[key]
        if key == "R_am" and raw is None:
            arrays[key] = np.eye(3)
            continue
        if _has_bool(raw):
            raise ValueError(f"{key} must hold numbers, not true/false")
        a = np.array(raw, dtype=float)
        if a.shape != shape or not np.all(np.isfinite(a)):
            raise ValueError(f"{key} must be {'3x3' if len(shape) == 2 else '3'} finite numbers")
        arrays[key] = a
    if abs(np.linalg.det(arrays["M"])) < 1e-12 * np.abs(arrays["M"]).max() ** 3:
        raise ValueError("M is singular")
    R = arrays["R_am"]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise ValueError("R_am must be a rotation")
    unit = d.get("unit")
    field = d.get("field")
    if field is not None and (_number(field, "field") <= 0):
        raise ValueError(f"field must be a positive number, got {field!r}")
    return MagModel(M=arrays["M"], b=arrays["b"], R_am=R,
                    unit=unit if isinstance(unit, str) else None,
                    field=None if field is None else float(field))


def _number(x: Any, what: str) -> float:
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        raise ValueError(f"{what} must be a number, got {x!r}")
    v = float(x)
    if not math.isfinite(v):
        raise ValueError(f"{what} must be finite, got {v!r}")
    return v


def _model(d: dict) -> SensorModel:
    """One sensor's T, K, b (M2, M4), refused unless the model is a bijection with finite
    numbers: a singular T or a zero scale would map every sample onto a plane or a line."""
    arrays = {}
    for key, shape in (("T", (3, 3)), ("K", (3,)), ("b", (3,))):
        raw = d[key]
        if _has_bool(raw):
            raise ValueError(f"{key} must hold numbers, not true/false")
        a = np.array(raw, dtype=float)
        if a.shape != shape:
            raise ValueError(f"{key} must be {'3x3' if key == 'T' else '3 numbers'}, got shape "
                             f"{a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{key} must be finite numbers (null is not a number)")
        arrays[key] = a
    if np.any(arrays["K"] == 0):
        raise ValueError("a scale factor in K is zero")
    cond = np.linalg.cond(arrays["T"])
    if not cond < 1e12:  # beyond: T's inverse loses more than 12 of double's 16 digits
        raise ValueError(f"T is singular (condition number {cond:.3g})")
    return SensorModel(T=arrays["T"], K=arrays["K"], b=arrays["b"])


def _has_bool(x: Any) -> bool:
    if isinstance(x, list):
        return any(_has_bool(v) for v in x)
    return isinstance(x, bool)
