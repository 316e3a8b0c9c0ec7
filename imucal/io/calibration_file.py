"""The calibration file: a JSON contract other tools rely on (format ``imucal-calibration``).

Saving writes the format name and version, the model conventions as text and the units;
loading checks them and refuses a file of another format or an unknown version.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from imucal.errors import ImucalError
from imucal.io.atomic import write_text_atomic
from imucal.io.calibration_sections import (
    magnetometer_section,
    temperature_section,
    triads_section,
)
from imucal.io.json_numbers import json_number as _f
from imucal.io.json_numbers import json_numbers as _fl
from imucal.io.noise_json import noise_to_dict
from imucal.models import ACC_PARAM_NAMES, GYRO_PARAM_NAMES, SensorModel
from imucal.stages.apply import Calibration

if TYPE_CHECKING:
    from imucal.result import Result
    from imucal.stages.group import Grouping
    from imucal.stages.gyro import GyroFit
    from imucal.stages.quality import BeforeAfter

FORMAT = "imucal-calibration"
# Version 2: segments are numbered from 1 everywhere (a warning's "segment", as the CLI prints
# it and ``imucal export --segment`` takes it; version 1 wrote its 0-based position), and the
# run's verdict is a top-level "verdict" object. Version-1 files load through MIGRATIONS[1].
FORMAT_VERSION = 2
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


def _before_after(x: BeforeAfter) -> dict:
    return {"before": _f(x.before), "after": _f(x.after)}


def _model_dict(model: SensorModel, std: np.ndarray, names: tuple[str, ...]) -> dict:
    return {"T": _fl(model.T), "K": _fl(model.K), "b": _fl(model.b),
            "std": {n: _f(s) for n, s in zip(names, std)}}


def _grouping_dict(grouping: Grouping) -> dict:
    """How the static blocks became segments (method.md §2), with every split test's figures."""
    return {
        "mode": grouping.mode,
        "split_alpha": _f(grouping.alpha),
        "delta": _f(grouping.delta),
        "segments": [[a, b] for a, b in grouping.segments],  # [first block, last block + 1)
        "tests": [{"blocks": [t.start, t.end], "boundary": t.block,
                   "boundaries_tried": t.boundaries, "change": _f(t.change), "f": _f(t.f),
                   "dof": list(t.dof), "p_value": _f(t.p_value), "p_adjusted": _f(t.p_adjusted),
                   "f_critical": _f(t.f_critical), "noise_ratio": _f(t.noise_ratio),
                   "split": t.split, "reason": t.reason} for t in grouping.tests],
    }


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
                              "end": _f(seg.gyro.report.cost)}} | _gyro_cv_keys(seg.gyro)
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
        "units": result.calibration.to_dict()["units"],
        "source": {"file": s.source, "sha256": s.sha256} | (
            {"streams": list(s.chosen)} if s.chosen else {}),
        "settings": {k: (list(v) if isinstance(v, tuple) else v)
                     for k, v in result.settings.to_dict().items()},
        "detector": _detector_dict(result),
        "grouping": _grouping_dict(result.grouping),
        "segments": segs,
        "static_blocks": [[_f(a), _f(b)] for a, b in result.block_times],
        "lcurve": lcurve,
        "lambda": _f(result.whole.lam),
        "quality": {
            "static_norm_rms_mg": _before_after(q.static_norm_rms_mg) | {
                "cross_validated": _f(q.static_norm_cv_mg)},
            "sample_norm_rms_mg": _before_after(q.sample_norm_rms_mg) | {
                "note": "single samples: dominated by sensor noise"},
            "gravity_angle_rms_deg": None if ga is None else _before_after(ga) | {
                "cross_validated": _f(q.gravity_angle_cv_deg)},
            "notes": list(q.notes),
        },
        # The sensor's noise from the still blocks (white noise density per axis; bias
        # instability and random walk only where the blocks are long enough to show them).
        "noise": noise_to_dict(result.noise),
        "warnings": [w.to_dict() for w in result.warnings],  # {code, segment, message}
        "guide": None if result.guide is None else result.guide.to_dict(),
        # The run judged (imucal.stages.verdict): level, the one reason, the next step.
        "verdict": None if result.verdict is None else result.verdict.to_dict(),
    } | magnetometer_section(result) | (
        {"triads": triads_section(result, result_to_dict)} if result.triads else {}) | (
        {"temperature": temperature_section(result)} if result.temperature else {})


def _gyro_cv_keys(fit: GyroFit) -> dict:
    """The gyroscope's bias choice and its gravity prediction error in and out of sample
    (method.md §4, §5)."""
    cv = fit.cv
    fitted = ~fit.excluded
    in_sample = float(np.sqrt(np.mean(np.square(fit.angle_after[fitted]))))
    return {"bias_optimised": bool(cv.optimise_bias),
            "bias_optimised_by": {"setting": "setting optimise_gyro_bias"}.get(cv.how, cv.how),
            "gravity_angle_rms_deg": {"in_sample": _f(in_sample), "cross_validated": _f(cv.rms)},
            "cross_validation": {
                "folds": cv.folds,
                "gravity_angle_rms_deg": {"static_bias": _f(cv.rms_static_bias),
                                          "optimised_bias": _f(cv.rms_optimised_bias)},
                "note": "each rotation between still poses predicted by the fit without its "
                        "fold (K-fold, folds dealt in turn); null: that fit not made"}}


def _detector_dict(result: Result) -> dict:
    """The static detector's values, and how they were chosen (method.md §1)."""
    det = result.detection
    tun = det.tuning
    out = {"window": det.window, "min_len": det.min_len, "k": _f(det.k),
           "threshold": _f(det.threshold), "reference_level": _f(det.s2_init),
           "initial_interval": None if det.init is None else [_f(x) for x in det.init],
           "outliers": [int(i) for i in det.outliers]}
    if tun is not None:
        out |= {"tuned": list(tun.tuned), "reference": tun.reference,
                "local_factor": _f(tun.local_factor), "quiet_level": _f(tun.quiet_level),
                "hold_s": _f(tun.hold_s), "reason": tun.reason, "chosen": tun.chosen,
                "candidates": [{"window": c.window, "min_len": c.min_len, "k": _f(c.k),
                                "blocks": c.blocks, "orientations": c.orientations,
                                "score_mg": _f(c.score_mg)} for c in tun.candidates]}
    return out


def save_calibration(result: Result, path: str | os.PathLike) -> None:
    """Write the calibration file atomically (temporary file, then rename)."""
    text = json.dumps(result_to_dict(result), indent=2, allow_nan=False) + "\n"
    write_text_atomic(path, text)


def load_calibration(path: str | os.PathLike) -> Calibration:
    """Read a calibration file back into a :class:`Calibration` that can ``apply`` a session.

    Every parameter is checked here, so that a hand-edited or damaged file is one clear error
    and never a calibration that silently zeroes or scrambles a signal: T finite and
    invertible, K finite and non-zero, b finite (M2, M4); g finite and > 0; the units known;
    the segments in time order; the format version an integer this imucal reads.
    """
    return calibration_from_dict(_read_json(path), source=str(path))


def recorded_units(path: str | os.PathLike) -> tuple[Calibration, dict[str, str]]:
    """The calibration at ``path`` and the units of the recording it was fitted on, as
    :func:`~imucal.io.load.load_session`'s ``acc_unit`` and ``gyro_unit``: what a recording of
    the same sensor is read in when no unit is given (``imucal noise --calibration``, where a
    still gyroscope cannot tell rad/s from deg/s). The file's ``units`` give them, except that a
    gyroscope read in deg/s was converted to rad/s on load: the loader's note, which the file
    keeps among its warnings, says so."""
    from imucal.io.load import DEG_S_NOTE

    data = _read_json(path)
    cal = calibration_from_dict(data, source=str(path))
    units = {"acc_unit": cal.acc_unit_raw}
    if cal.gyro_unit_raw is not None:
        notes = [w.get("message") for w in data.get("warnings") or () if isinstance(w, dict)]
        units["gyro_unit"] = "deg/s" if DEG_S_NOTE in notes else cal.gyro_unit_raw
    return cal, units


def _read_json(path: str | os.PathLike) -> Any:
    name = str(path)
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ImucalError("file not found", source=name) from None
    except RecursionError:
        raise ImucalError("not a calibration file: JSON nested too deeply", source=name
                          ) from None
    except OSError as e:
        raise ImucalError(f"cannot be read ({e.strerror or e.__class__.__name__})", source=name
                          ) from None
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ImucalError(f"not a readable JSON calibration file ({e.__class__.__name__})",
                          source=name) from None


def calibration_to_dict(cal: Calibration) -> dict:
    """A calibration file with the calibration alone (no run behind it): what
    :func:`calibration_from_dict` and ``imucal apply`` read."""
    return {"format": FORMAT, "format_version": FORMAT_VERSION, "conventions": CONVENTIONS,
            **cal.to_dict()}


def _v1_to_v2(data: dict) -> dict:
    """Version 1 named a warning's segment by its 0-based position; version 2 by its number
    from 1. A version-1 file has no verdict (it stays without one: nothing judged it)."""
    data = dict(data)
    warnings = data.get("warnings")
    if isinstance(warnings, list):
        data["warnings"] = [
            w | {"segment": w["segment"] + 1}
            if isinstance(w, dict) and type(w.get("segment")) is int else w
            for w in warnings]
    return data


# Upgrades of older calibration files: MIGRATIONS[n] turns a version-n dict into version n + 1,
# so every older file still loads; a file newer than this imucal is refused, never guessed at.
MIGRATIONS: dict[int, Callable[[dict], dict]] = {1: _v1_to_v2}


def migrate(data: dict, source: str = "calibration") -> dict:
    """``data`` (a parsed calibration file) brought to :data:`FORMAT_VERSION`."""
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise ImucalError(f"expected format {FORMAT!r}", source=source, field="format")
    version = data.get("format_version")
    if type(version) is not int or not 1 <= version <= FORMAT_VERSION or (
            version < FORMAT_VERSION and version not in MIGRATIONS):
        # bool is an int in Python: true is not a version
        raise ImucalError(f"format_version {version!r} is not supported (this imucal reads "
                          f"version {FORMAT_VERSION})", source=source, field="format_version")
    while version < FORMAT_VERSION:
        data = MIGRATIONS[version](data)
        version += 1
        data["format_version"] = version
    return data


def calibration_from_dict(data: dict, source: str = "calibration") -> Calibration:
    """The :class:`Calibration` in a parsed calibration file, migrated to this format version
    and checked parameter by parameter (:meth:`Calibration.from_dict`)."""
    data = migrate(data, source)
    try:
        cal = Calibration.from_dict(data)
    except ImucalError as e:
        raise ImucalError(e.problem, source=source, field=e.field) from None
    check_plausible(cal, source)
    return cal


# Plausibility (issue 27): a model apply or an export could use, but no sensor has. Every reader
# of a calibration file comes through calibration_from_dict, so apply and every export refuse
# what calibrate itself calls not physical. The bounds are wide: they catch a hand edit gone
# wrong (a sign, K and b swapped, the two sensors' models swapped, 1e308), not a poor sensor.
_SI = {"g": 9.80665, "m/s^2": 1.0, "rad/s": 1.0, "deg/s": np.pi / 180}
_SCALE_BAND = 10.0  # K within 1/10 to 10 times the units' own ratio (calibrate warns at 2)
_COUNT_SCALE = (1e-12, 10.0)  # calibrated units per count: any real sensor's resolution
_SCALE_RATIO = 10.0  # a triad's axes have one sensitivity to a few percent
_MAX_MISALIGNMENT = 1.0  # an off-diagonal of T beyond tan 45 deg is no misalignment
_MAX_BIAS_SI = {"accelerometer": 10 * 9.80665, "gyroscope": 10.0}  # m/s^2, rad/s: no MEMS part
_MAX_COUNT = 2.0**32  # raw counts: no converter gives more


def check_plausible(cal: Calibration, source: str) -> None:
    """Refuse a calibration no sensor has, in one line naming the file and the field."""
    ratio = cal.g / (1.0 if cal.acc_unit == "g" else _SI["g"])
    if not 0.1 <= ratio <= 10:
        raise ImucalError(f"g = {cal.g:g} {cal.acc_unit} is not a gravity (expected near "
                          f"{_SI['g'] / _SI[cal.acc_unit]:g})", source=source, field="units.g")
    for i, seg in enumerate(cal.segments):
        sensors = [("accelerometer", seg.acc, cal.acc_unit_raw, cal.acc_unit)]
        if seg.gyro is not None:
            sensors.append(("gyroscope", seg.gyro, cal.gyro_unit_raw, "rad/s"))
        for sensor, model, raw, out in sensors:
            why = _implausible(sensor, model, raw, out)
            if why is not None:
                key, problem = why
                raise ImucalError(f"{problem}: no sensor has this model; was the file edited?",
                                  source=source, field=f"segments[{i}].{sensor}.{key}")


def _implausible(sensor: str, model, raw: str | None, out: str) -> tuple[str, str] | None:
    T, K, b = model.T, model.K, model.b
    lower = T[np.tril_indices(3, -1)]
    off = T[~np.eye(3, dtype=bool)]
    if np.any(np.abs(np.diag(T) - 1) > 1e-9):
        return "T", f"T's diagonal {_v(np.diag(T))} is not 1 (method.md M2, M4)"
    if sensor == "accelerometer" and np.any(np.abs(lower) > 1e-9):
        return "T", (f"T has entries {_v(lower)} below its diagonal, but the accelerometer's T "
                     "is upper triangular (method.md M2): is this the gyroscope's model?")
    if np.any(np.abs(off) > _MAX_MISALIGNMENT):
        return "T", f"misalignment {_v(off)} beyond 45 degrees"
    if np.any(K < 0):
        return "K", f"negative scale factor in K {_v(K)}"
    if K.max() > _SCALE_RATIO * K.min():
        return "K", f"scale factors K {_v(K)} differ by more than {_SCALE_RATIO:g} times"
    if raw in _SI:
        nominal = _SI[raw] / _SI[out]
        if not (nominal / _SCALE_BAND <= K.min() and K.max() <= nominal * _SCALE_BAND):
            return "K", (f"K {_v(K)} is no scale from {raw} to {out} (expected near "
                         f"{nominal:.4g}): are K and b swapped, or the units wrong?")
    elif not (_COUNT_SCALE[0] <= K.min() and K.max() <= _COUNT_SCALE[1]):
        return "K", f"K {_v(K)} {out} per count is no sensor's resolution"
    if raw not in _SI:
        # Raw counts: an unsigned ADC's zero sits mid-range (32768 counts: 16 g of a +-16 g
        # part), so only a count no converter gives is refused.
        if not np.all(np.abs(b) <= _MAX_COUNT):
            return "b", f"bias b {_v(b)} counts is beyond any converter's range (2^32)"
        return None
    with np.errstate(over="ignore", invalid="ignore"):  # 1e308: refused just below
        bias = model.matrix @ b
        bias_si = np.abs(bias) * _SI[out]
    if not np.all(bias_si <= _MAX_BIAS_SI[sensor]):
        limit = _MAX_BIAS_SI[sensor] / _SI[out]
        return "b", (f"bias b {_v(b)} {raw} is {_v(bias)} {out} once calibrated, "
                     f"beyond {limit:g} {out}: are K and b swapped?")
    return None


def _v(x) -> str:
    return "[" + ", ".join(f"{float(v):.4g}" for v in np.ravel(x)) + "]"


