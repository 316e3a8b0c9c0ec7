"""One row of a batch's summary table per session: a :class:`~imucal.result.Result` (or the
error that stopped it) as flat columns, and the table's schema (one place, so that a batch of
failures still writes every column with its type).

Parameters are those of the first segment (method.md §2: a session split by a change of error
conditions has several; ``segments`` says how many), in the conventions of calib.json: M2 for
the accelerometer, M4 for the gyroscope, biases in the raw unit (``acc_unit_raw``).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

from imucal.models import ACC_PARAM_NAMES, GYRO_PARAM_NAMES

if TYPE_CHECKING:
    from imucal.result import Result

GYRO_BIAS_NAMES = ("b_x", "b_y", "b_z")

# Status of a row: "ok" calibrated; "failed" the input was refused (an ImucalError: the same
# file fails the same way again); "error" anything else (a bug, a worker lost for good: worth
# a retry on the next run); "duplicate" the same bytes as another session's file.
STATUSES = ("ok", "failed", "error", "duplicate")

_ID_COLUMNS: dict[str, str] = {
    "device": "str", "device_from": "str", "session": "str", "path": "str",
    "recorded_at": "datetime", "recorded_from": "str", "calibrated_at": "datetime",
    "sha256": "str", "settings_hash": "str", "spec_hash": "str", "status": "str", "error": "str",
    "duplicate_of": "str", "calib_path": "str", "worker": "str", "blas_threads": "str",
    "seconds": "float", "worker_peak_mb": "float",
}
_RESULT_COLUMNS: dict[str, str] = {
    "acc_unit_raw": "str", "gyro_unit_raw": "str", "duration_s": "float", "static_blocks": "int",
    "segments": "int", "lambda": "float",
    **{f"acc_{n}": "float" for n in ACC_PARAM_NAMES},
    **{f"acc_std_{n}": "float" for n in ACC_PARAM_NAMES},
    **{f"gyro_{n}": "float" for n in GYRO_PARAM_NAMES + GYRO_BIAS_NAMES},
    **{f"gyro_std_{n}": "float" for n in GYRO_PARAM_NAMES},
    "static_norm_rms_mg_before": "float", "static_norm_rms_mg_after": "float",
    "sample_norm_rms_mg_before": "float", "sample_norm_rms_mg_after": "float",
    "gravity_angle_rms_deg_before": "float", "gravity_angle_rms_deg_after": "float",
    # the same figures out of sample (method.md §5): blocks and turns held out of the fit
    "static_norm_rms_mg_cv": "float", "gravity_angle_rms_deg_cv": "float",
    # the run judged (imucal.stages.verdict), a maker's limits folded in when a spec is given
    "verdict": "str", "verdict_reason": "str", "verdict_next": "str",
    "warnings": "list",
}
_SPEC_COLUMNS: dict[str, str] = {"spec_pass": "bool", "spec_broken": "list",
                                 "spec_unchecked": "list"}
COLUMNS: dict[str, str] = {**_ID_COLUMNS, **_RESULT_COLUMNS, **_SPEC_COLUMNS}
RESULT_COLUMNS = tuple(_RESULT_COLUMNS)


def _num(x: Any) -> float | None:
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def result_columns(result: Result) -> dict[str, Any]:
    """The columns a calibration fills (the identity and spec columns are the driver's)."""
    from imucal.models import acc_theta, gyro_theta

    s, q = result.session, result.quality
    seg = result.segments[0]
    row: dict[str, Any] = {
        "acc_unit_raw": s.acc_unit, "gyro_unit_raw": s.gyro_unit if s.has_gyro else None,
        "duration_s": _num(s.duration), "static_blocks": len(result.detection.blocks),
        "segments": len(result.segments), "lambda": _num(seg.acc.lam),
    }
    th = acc_theta(seg.acc.model)
    row |= {f"acc_{n}": _num(v) for n, v in zip(ACC_PARAM_NAMES, th)}
    row |= {f"acc_std_{n}": _num(v) for n, v in zip(ACC_PARAM_NAMES, seg.acc.std)}
    if seg.gyro is not None:
        gt = gyro_theta(seg.gyro.model)
        row |= {f"gyro_{n}": _num(v) for n, v in zip(GYRO_PARAM_NAMES, gt)}
        row |= {f"gyro_{n}": _num(v) for n, v in zip(GYRO_BIAS_NAMES, seg.gyro.model.b)}
        row |= {f"gyro_std_{n}": _num(v) for n, v in zip(GYRO_PARAM_NAMES, seg.gyro.std)}
    for name, pair in (("static_norm_rms_mg", q.static_norm_rms_mg),
                       ("sample_norm_rms_mg", q.sample_norm_rms_mg),
                       ("gravity_angle_rms_deg", q.gravity_angle_rms_deg)):
        before, after = (pair.before, pair.after) if pair is not None else (None, None)
        row[f"{name}_before"], row[f"{name}_after"] = _num(before), _num(after)
    row["static_norm_rms_mg_cv"] = _num(q.static_norm_cv_mg)
    row["gravity_angle_rms_deg_cv"] = _num(q.gravity_angle_cv_deg)
    row |= verdict_columns(result.verdict)
    row["warnings"] = [w.text for w in result.warnings] + list(q.notes)
    return row


def verdict_columns(verdict) -> dict[str, Any]:
    """The verdict's columns of a row (``None`` where the run has none)."""
    if verdict is None:
        return {"verdict": None, "verdict_reason": None, "verdict_next": None}
    return {"verdict": verdict.level, "verdict_reason": verdict.reason,
            "verdict_next": verdict.next_step}


def empty_row() -> dict[str, Any]:
    """Every column, unset (lists empty)."""
    return {name: ([] if kind == "list" else None) for name, kind in COLUMNS.items()}


def to_frame(rows: list[dict[str, Any]]):
    """The rows as a polars DataFrame with the summary's schema (column order fixed)."""
    import polars as pl

    types = {"str": pl.String, "float": pl.Float64, "int": pl.Int64, "bool": pl.Boolean,
             "list": pl.List(pl.String), "datetime": pl.Datetime("us", "UTC")}
    schema = {name: types[kind] for name, kind in COLUMNS.items()}
    full = [empty_row() | {k: v for k, v in r.items() if k in COLUMNS} for r in rows]
    return pl.DataFrame(full, schema=schema, orient="row")
