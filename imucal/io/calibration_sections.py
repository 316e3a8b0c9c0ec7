"""The sections of calib.json for the sensors beside the calibrated pair: the magnetometer
(method.md §9, M8), the other triads (§11) and the temperature models (§12), each written
only when the session has it, so that a session without keeps its file byte for byte."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from imucal.io.json_numbers import json_number as _f
from imucal.io.json_numbers import json_numbers as _fl

if TYPE_CHECKING:
    from imucal.result import Result


MAG_MODEL = ("m = R_am M (m_raw - b) (imucal M8): b the hard iron and M the soft iron (symmetric, "
             "det M = 1) in the raw unit, so |m| = field in the raw unit; R_am the rotation from "
             "the magnetometer's corrected frame to the accelerometer's calibrated frame (M2's); "
             "u . m / field = -sin(dip) for the calibrated accelerometer's up u when still. "
             "R_am and the dip from the still blocks and, where the gyroscope is calibrated, "
             "from the turns between them (R_am h_k = R_k^T R_am h_(k-1), h the corrected "
             "field's direction, R_k the calibrated gyroscope's integrated rotation: M8t) in "
             "one weighted fit; R_am_from says which evidence determined R_am. "
             "std.R_am_deg: small rotations about the accelerometer's x, y, z axes. Fitted over "
             "the whole session.")


def magnetometer_section(result: Result) -> dict:
    """The ``magnetometer`` section, only for a session holding one (a session without keeps
    its calibration file byte for byte)."""
    stream = result.session.magnetometer
    if stream is None:
        return {}
    fit = result.magnetometer
    if fit is None:
        said = [w for w in result.warnings if w.code in ("mag_not_calibrated", "mag_disturbed")]
        return {"magnetometer": {"model": MAG_MODEL, "stream": stream.name, "unit": stream.unit,
                                 "calibrated": False,
                                 "reasons": [w.message for w in said]}}
    q = fit.quality
    return {"magnetometer": {
        "model": MAG_MODEL, "stream": fit.stream, "unit": fit.unit, "calibrated": True,
        "M": _fl(fit.M), "b": _fl(fit.b),
        "R_am": None if fit.R_am is None else _fl(fit.R_am),
        "R_am_from": None if fit.alignment is None else _alignment(fit.alignment.to_dict()),
        "field": _f(fit.field), "dip_deg": _f(fit.dip_deg),
        "std": {"M": _fl(fit.std_M), "b": _fl(fit.std_b), "field": _f(fit.std_field),
                "dip_deg": _f(fit.std_dip_deg),
                "R_am_deg": None if fit.std_R_am_deg is None else _fl(fit.std_R_am_deg)},
        "quality": {"norm_rms_pct": {"in_sample": _f(q.norm_rms_pct),
                                     "held_out": _f(q.norm_rms_held_out_pct),
                                     "note": "|m| / field - 1; held out: each half of the "
                                             "recording's time judged by the other's fit"},
                    "dip_spread_deg": _f(q.dip_spread_deg), "coverage": _f(q.coverage),
                    "missing": q.missing, "still_blocks": q.blocks,
                    "heading_std_deg": _f(q.heading_std_deg),
                    "std_design_effect": _f(fit.se_design_effect),
                    "std_block_s": _f(fit.se_block_s),
                    "std_note": "the ellipsoid's standard errors are sqrt(std_design_effect) "
                                "times those of independent samples: the norm residual is "
                                "correlated along the recording, measured by a block "
                                "jackknife of std_block_s seconds (method.md M8s)"},
        "samples": fit.samples, "samples_used": int(fit.used.sum()), "start": fit.start,
        "soft_iron_estimated": fit.soft_iron,
        "undetermined": list(fit.undetermined), "lambda": _f(fit.lam),
        "lcurve": _mag_lcurve(fit.lcurve),
        "disturbances": [d.to_dict() for d in fit.disturbances]}}


def _mag_lcurve(lc: Any) -> dict | None:
    """M8r's L-curve (imucal.stages.accel.LCurve of the shape's Tikhonov term)."""
    if lc is None:
        return None
    return {"lambdas": _fl(lc.lambdas), "residual_norm": _fl(lc.residual_norm),
            "solution_norm": _fl(lc.solution_norm), "corner": int(lc.corner),
            "well_posed": bool(lc.well_posed),
            "note": "M8r: residual_norm the RMS norm residual (raw unit), solution_norm "
                    "|M / (tr M / 3) - I|_F, at each lambda whose fit is a physical "
                    "ellipsoid; corner the index of the lambda chosen (method.md §9)"}


def _alignment(d: dict) -> dict:
    """What determined R_am (imucal.stages.mag_align.Alignment), its figures JSON numbers."""
    return {k: _f(v) if isinstance(v, float) else v for k, v in d.items()}


def temperature_section(result: Result) -> dict:
    """Each sensor's bias in temperature (method.md §12, M16); only written when fitted."""
    out = {"model": "b(T) = b0 + sum_j coefficients[j] (T - reference_degC)^j, T held inside "
                    "span_degC (never extrapolated), raw units per degC^j (method.md M16); "
                    "the accelerometer's K(T) = K (1 + scale_slope_per_degC (T - "
                    "reference_degC)) where a slope was fitted"}
    for f in result.temperature:
        out[f.sensor] = {
            "b0": _fl(f.b0), "reference_degC": _f(f.t0), "span_degC": [_f(f.span[0]),
                                                                       _f(f.span[1])],
            "order": f.order, "coefficients": _fl(f.coefs),
            "cv_rms_by_order": [_f(v) if np.isfinite(v) else None for v in f.cv_rms],
            "static_blocks": f.blocks, "hysteresis": f.hysteresis,
            "scale_slope_per_degC": None if f.scale_slope is None else _fl(f.scale_slope),
            "notes": list(f.notes)} | (
            # M2's T and K fitted beside the polynomial (M17): the model b(T) belongs to
            {"T": _fl(f.model.T), "K": _fl(f.model.K)} if f.model is not None else {}) | (
            _judged(result) if f.sensor == "accelerometer" else {})
    return out


def _judged(result: Result) -> dict:
    """The accelerometer's static norm error with its bias in temperature, the figures the
    verdict judged, beside the constant fit's (method.md §8); {} where not computed."""
    from imucal.report import in_temperature

    heat = in_temperature(result)
    if heat is None:
        return {}
    q = result.quality
    return {"static_norm_rms_mg": {
        "in_sample": _f(heat[0]), "held_out": _f(heat[1]), "static_blocks": heat[2],
        "held_out_blocks": heat[3],
        "constant": {"in_sample": _f(q.static_norm_rms_mg.after),
                     "held_out": _f(q.static_norm_cv_mg)},
        "note": "|a| against |g| on the still poses with the bias in temperature, as apply "
                "calibrates; held out: each block predicted by the fit in temperature made "
                "again without it (its order chosen again), the blocks outside the others' "
                "span (a ramp's ends) not scored, as the order's cross-validation scores them"}}


def triads_section(result: Result, result_to_dict: Callable[[Result], dict]) -> dict:
    """The session's other triads (method.md §11): each one's own calibration (its segments,
    quality and verdict, as for the reference), its rotation to the reference with the standard
    error, and the agreement of the two once calibrated. Only written when there are some, so a
    session of one triad writes the file it always did."""
    out = []
    for tri in result.triads:
        entry: dict[str, Any] = {"accelerometer": tri.name, "gyroscope": tri.gyro,
                                 "clock_offset_s": _f(tri.clock_offset_s)}
        if tri.result is not None:
            own = result_to_dict(tri.result)
            entry |= {"units": own["units"], "segments": own["segments"],
                      "quality": own["quality"], "verdict": own["verdict"],
                      "warnings": own["warnings"]} | (
                {"temperature": own["temperature"]} if "temperature" in own else {})
        a = tri.agreement
        if a is not None:
            rot = a.rotation
            entry |= {
                "rotation_to_reference": _fl(rot.R),
                "rotation_angle_deg": _f(a.angle_deg),
                "rotation_std_deg": {"about_x": _f(rot.std_deg[0]), "about_y": _f(rot.std_deg[1]),
                                     "about_z": _f(rot.std_deg[2]),
                                     "total": _f(rot.std_total_deg)},
                "shared_static_blocks": a.blocks,
                "agreement_mg": {"before": {"rms": _f(a.before_rms_mg)},
                                 "after_held_out": {"rms": _f(a.held_out_rms_mg),
                                                    "max": _f(float(np.max(a.held_out_mg)))}},
            }
        if tri.gyro_agreement is not None:  # M14: the gyroscope's own rotation, from the turns
            ga = tri.gyro_agreement
            gr = ga.rotation
            entry["gyroscope_rotation"] = {
                "rotation_to_reference": _fl(gr.R),
                "rotation_std_deg": {"about_x": _f(gr.std_deg[0]), "about_y": _f(gr.std_deg[1]),
                                     "about_z": _f(gr.std_deg[2]),
                                     "total": _f(gr.std_total_deg)},
                "turns": ga.turns, "turn_residual_rms_deg": _f(ga.residual_rms_deg),
                "angle_to_accelerometer_rotation_deg": _f(ga.accel_difference_deg)}
        v = tri.against_reference
        if v is not None:  # M15: its M2 fitted to the reference's calibrated gravity vectors
            entry["against_reference"] = {
                "T": _fl(v.model.T), "K": _fl(v.model.K), "b": _fl(v.model.b),
                "std": {n: _f(x) for n, x in zip(("s_x", "s_y", "s_z", "b_x", "b_y", "b_z"),
                                                 np.r_[v.std_K, v.std_b])},
                "rotation_to_reference": _fl(v.R), "residual_rms_mg": _f(v.rms_mg),
                "static_blocks": v.blocks,
                "note": "the triad's M2 fitted to the reference's calibrated gravity vectors "
                        "(method.md M15): three equations per still block; the reference's own "
                        "errors pass into it and are not in these standard errors"}
        if tri.result is not None:  # the shift its times were given (§11's two clocks)
            shift = float(next(s.t[0] for s in result.session.others if s.name == tri.name)
                          - tri.result.session.t_acc[0])
            entry["times_moved_by_s"] = _f(0.0 - shift)
        entry["said"] = list(tri.said)
        out.append(entry)
    chosen = result.session.chosen
    return {"reference": chosen[0] if chosen else "the calibrated accelerometer",
            "convention": "u_ref = R u_triad (method.md M12): R turns a triad's calibrated "
                          "vector into the reference triad's frame; std in degrees about the "
                          "reference's axes, total = sqrt(trace of the covariance)",
            "triads": out} | combined_section(result)


def combined_section(result: Result) -> dict:
    """The low-range and high-range accelerometers combined (method.md M18), only where the
    run's triads are such a pair (or were stated to be)."""
    c = result.combined
    if c is None:
        return {}
    if c.spec is None:
        return {"combined": {"combined": False, "said": list(c.said)}}
    spec, step = c.spec, c.step
    return {"combined": {
        "combined": True,
        "model": "a_C = (1 - w) a_L + w a_H, w = s((u - u_1) / (u_2 - u_1)), s(z) = 3z^2 - 2z^3 "
                 "on [0, 1], u = max_i |x_L,i - (hi_i + lo_i)/2| / ((hi_i - lo_i)/2) of the "
                 "low-range triad's raw reading (method.md M18); both calibrated, in the "
                 "reference's frame",
        "low_range": spec.low, "high_range": spec.high,
        "low_range_limits_raw": {"lo": _fl(spec.levels.lo), "hi": _fl(spec.levels.hi),
                                 "how": spec.levels.how},
        "band": [_f(spec.band[0]), _f(spec.band[1])],
        "high_range_noise_mg": _f(spec.high_noise_mg),
        "step_at_switch_mg": None if step is None else {
            "norm": _f(step.mg), "vector": _fl(step.vector_mg), "std": _f(step.std_mg),
            "samples": step.samples,
            "note": "the mean of a_H - a_L over this session's samples inside the band"},
        "said": list(c.said)}}
