"""The calibration file: a JSON contract other tools rely on (format ``imucal-calibration``).

Saving writes the format name and version, the model conventions as text and the units;
loading checks them and refuses a file of another format or an unknown version.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from imucal.errors import ImucalError
from imucal.io.atomic import write_text_atomic
from imucal.io.noise_json import noise_to_dict
from imucal.models import ACC_PARAM_NAMES, GYRO_PARAM_NAMES, SensorModel
from imucal.stages.apply import Calibration, SegmentModels
from imucal.stages.noise import still_noise

if TYPE_CHECKING:
    from imucal.result import Result

FORMAT = "imucal-calibration"
FORMAT_VERSION = 1
CONVENTIONS = {
    "accelerometer": "a = T K (a_raw - b) (Tedaldi et al. 2014; method.md M2), "
                     "T = [[1, -a_yz, a_zy], [0, 1, -a_zx], [0, 0, 1]], K = diag(s_x, s_y, s_z), "
                     "b in raw units. The thesis's code subtracts the bias after T K instead: "
                     "b_thesis = T K b.",
    "gyroscope": "w = T_g K_g (w_raw - b_g) (method.md M4), "
                 "T_g = [[1, g_yz, g_zy], [g_xz, 1, g_zx], [g_xy, g_yx, 1]], "
                 "K_g = diag(s_x, s_y, s_z), b_g in raw units; w in rad/s.",
    "segments": "each segment's parameters apply from its t_start to its t_end (the first from "
                "the start of time, the last to its end); between two segments, the mean of "
                "the two segments' parameters.",
}


def _f(x: float | None) -> float | None:
    """JSON has no NaN or Infinity: write them as null."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def _fl(a: Any) -> Any:
    arr = np.asarray(a, dtype=float)
    if arr.ndim == 0:
        return _f(arr)
    return [_fl(v) for v in arr]


def _model_dict(model: SensorModel, std: np.ndarray, names: tuple[str, ...]) -> dict:
    return {"T": _fl(model.T), "K": _fl(model.K), "b": _fl(model.b),
            "std": {n: _f(s) for n, s in zip(names, std)}}


def result_to_dict(result: Result) -> dict:
    """The whole calibration file as a dict (stable key order: byte-identical output)."""
    s = result.session
    q = result.quality
    segs = []
    for seg in result.segments:
        acc = _model_dict(seg.acc.model, seg.acc.std, ACC_PARAM_NAMES)
        acc |= {"lambda": _f(seg.acc.lam), "start": seg.acc.report.start_name,
                "cost": {"start": _f(seg.acc.report.cost_start), "end": _f(seg.acc.report.cost)},
                "points": seg.acc.n_points}
        gyro = None
        if seg.gyro is not None:
            names = GYRO_PARAM_NAMES + (("b_x", "b_y", "b_z") if len(seg.gyro.std) > 9 else ())
            gyro = _model_dict(seg.gyro.model, seg.gyro.std, names)
            gyro |= {"lambda": _f(seg.gyro.lam), "bias_source": seg.gyro.bias_source,
                     "nominal_scale": _f(seg.gyro.nominal_scale),
                     "nominal_scale_source": seg.gyro.nominal_how,
                     "transitions": len(seg.gyro.u_meas),
                     "transitions_excluded": int(seg.gyro.excluded.sum()),
                     "cost": {"start": _f(seg.gyro.report.cost_start),
                              "end": _f(seg.gyro.report.cost)}}
        segs.append({"t_start": _f(seg.t_start), "t_end": _f(seg.t_end),
                     "static_blocks": seg.blocks[1] - seg.blocks[0],
                     "orientations": seg.orientations,
                     "accelerometer": acc, "gyroscope": gyro})
    lc = result.whole.lcurve
    lcurve = [] if lc is None else [
        {"lambda": _f(la), "residual_norm": _f(r), "solution_norm": _f(e)}
        for la, r, e in zip(lc.lambdas, lc.residual_norm, lc.solution_norm)]
    ga = q.gravity_angle_rms_deg
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "conventions": CONVENTIONS,
        "units": {"accelerometer_raw": s.acc_unit, "accelerometer": result.calibration.acc_unit,
                  "g": _f(result.calibration.g),
                  "gyroscope_raw": s.gyro_unit if s.has_gyro else None,
                  "gyroscope": "rad/s" if s.has_gyro else None, "time": "s"},
        "source": {"file": s.source, "sha256": s.sha256},
        "settings": {k: (list(v) if isinstance(v, tuple) else v)
                     for k, v in result.settings.to_dict().items()},
        "grouping": result.grouping.mode,
        "segments": segs,
        "static_blocks": [[_f(a), _f(b)] for a, b in result.block_times],
        "lcurve": lcurve,
        "lambda": _f(result.whole.lam),
        "quality": {
            "static_norm_rms_mg": {"before": _f(q.static_norm_rms_mg[0]),
                                   "after": _f(q.static_norm_rms_mg[1])},
            "sample_norm_rms_mg": {"before": _f(q.sample_norm_rms_mg[0]),
                                   "after": _f(q.sample_norm_rms_mg[1]),
                                   "note": "single samples: dominated by sensor noise"},
            "gravity_angle_rms_deg": None if ga is None else {"before": _f(ga[0]),
                                                              "after": _f(ga[1])},
            "notes": list(q.notes),
        },
        # The sensor's noise from the still blocks (white noise density per axis; bias
        # instability and random walk only where the blocks are long enough to show them).
        "noise": noise_to_dict(still_noise(result.calibrated, result.block_times)),
        "warnings": list(result.warnings),
    }


def save_calibration(result: Result, path: str | os.PathLike) -> None:
    """Write the calibration file atomically (temporary file, then rename)."""
    text = json.dumps(result_to_dict(result), indent=2, allow_nan=False) + "\n"
    write_text_atomic(path, text)


def load_calibration(path: str | os.PathLike) -> Calibration:
    """Read a calibration file back into a :class:`Calibration` that can ``apply`` a session."""
    name = str(path)
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ImucalError("file not found", source=name) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ImucalError(f"not a readable JSON calibration file ({e.__class__.__name__})",
                          source=name) from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise ImucalError(f"expected format {FORMAT!r}", source=name, field="format")
    if data.get("format_version") != FORMAT_VERSION:
        raise ImucalError(f"format_version {data.get('format_version')!r} is not supported "
                          f"(this imucal reads version {FORMAT_VERSION})", source=name,
                          field="format_version")
    try:
        units = data["units"]
        segments = []
        for i, seg in enumerate(data["segments"]):
            acc = _model(seg["accelerometer"])
            gyro = _model(seg["gyroscope"]) if seg.get("gyroscope") else None
            segments.append(SegmentModels(t_start=float(seg["t_start"]),
                                          t_end=float(seg["t_end"]), acc=acc, gyro=gyro))
            del i
        if not segments:
            raise ValueError("no segments")
        return Calibration(segments=tuple(segments), acc_unit_raw=units["accelerometer_raw"],
                           acc_unit=units["accelerometer"], g=float(units["g"]),
                           gyro_unit_raw=units.get("gyroscope_raw"))
    except (KeyError, TypeError, ValueError, IndexError) as e:
        raise ImucalError(f"malformed calibration ({e.__class__.__name__}: {e})", source=name,
                          field="segments") from None


def _model(d: dict) -> SensorModel:
    T = np.array(d["T"], dtype=float)
    K = np.array(d["K"], dtype=float)
    b = np.array(d["b"], dtype=float)
    if T.shape != (3, 3) or K.shape != (3,) or b.shape != (3,) or not (
            np.all(np.isfinite(T)) and np.all(np.isfinite(K)) and np.all(np.isfinite(b))):
        raise ValueError("T must be 3x3, K and b 3 finite numbers")
    return SensorModel(T=T, K=K, b=b)
