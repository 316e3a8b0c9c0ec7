"""The one-way flow: detect -> group -> accelerometer -> gyroscope -> apply -> result."""

from __future__ import annotations

import dataclasses

import numpy as np

from imucal.errors import ImucalError
from imucal.numerics.directions import distinct_orientations
from imucal.result import Result, Segment
from imucal.session import STANDARD_GRAVITY, Session, validate
from imucal.settings import Settings
from imucal.stages.accel import (
    block_mean_cov,
    calibrate_accelerometer,
    make_nominal,
    select_points,
)
from imucal.stages.accel_cv import leave_one_block_out
from imucal.stages.apply import Calibration, SegmentModels
from imucal.stages.detect import Detection, detect_static
from imucal.stages.group import block_mean_variance, group_blocks
from imucal.stages.gyro import calibrate_gyroscope
from imucal.stages.quality import quality_figures
from imucal.stages.saturation import blocks_with, saturated_mask
from imucal.warning import RunWarning


def resolve_g(session: Session, g: float | None) -> tuple[float, float, str]:
    """|g| in the raw unit, the calibrated output's norm and its unit (method.md §0)."""
    if g is not None and (not np.isfinite(g) or g <= 0):
        raise ImucalError(f"|g| must be a positive number, got {g}", source="settings", field="g")
    if session.acc_unit == "m/s^2":
        g_out = g if g is not None else STANDARD_GRAVITY
        g_in = g_out if g_out != 1.0 else STANDARD_GRAVITY
    else:
        g_out = g if g is not None else 1.0
        g_in = 1.0
    return g_in, g_out, "g" if g_out == 1.0 else "m/s^2"


def calibrate(session: Session, settings: Settings | None = None, **overrides) -> Result:
    """Calibrate a session: the whole method of method.md, one stage after the other."""
    try:
        settings = dataclasses.replace(settings or Settings(), **overrides)
    except TypeError as e:
        raise ImucalError(str(e), source="settings") from None
    validate(session)
    # How the input was read (units guessed, gaps bridged...): the loader's notes.
    warnings = [RunWarning("input", note) for note in session.notes]
    g_in, g_out, acc_unit = resolve_g(session, settings.g)

    det = detect_static(session.acc, session.t_acc, settings.detect, source=session.source)
    if det.note:  # the initial still interval was moved (method.md §1)
        warnings.append(RunWarning("init_interval_moved", det.note))
    det, excluded = _drop_saturated(session.acc, det)
    if excluded:
        warnings.append(RunWarning("acc_saturated_blocks", f"excluded {excluded} static block(s) "
                                   "holding saturated accelerometer samples (flat at the "
                                   "sensor's limit)"))
    _check_blocks(session, det, settings)
    gyro_sat = None
    if session.has_gyro:
        gyro_sat = saturated_mask(session.gyro)
        if gyro_sat.any():
            first = float(session.t_gyro[np.argmax(gyro_sat)])
            warnings.append(RunWarning("gyro_saturated", f"the gyroscope is saturated (flat at "
                                       f"its limit) in {int(gyro_sat.sum())} samples, first at "
                                       f"t = {first:.2f} s: rotations through them are "
                                       "under-measured; turn more slowly"))
    block_times = np.column_stack([session.t_acc[det.blocks[:, 0]],
                                   session.t_acc[det.blocks[:, 1] - 1]])
    if session.init_still_s is not None:  # a hint the file gave; only reported for now (§1)
        t0, t1 = block_times[0] - session.t_acc[0]
        warnings.append(RunWarning(
            "init_still_stated", f"the file states an initial still period of "
            f"{session.init_still_s:g} s; the first still block found spans {t0:.1f}-{t1:.1f} s"
            " (the stated length is not used by the detector)"))

    # A first whole-session fit: it gives the grouping calibrated magnitudes (method.md §2).
    whole = calibrate_accelerometer(session.acc, det.blocks, acc_unit=session.acc_unit,
                                    g_in=g_in, g_out=g_out, settings=settings.acc)
    means_n = whole.nominal.to_nominal(det.means)
    # The grouping fits block means, one point per block where M3 had n_points: scale lambda
    # so that the prior weighs the same against the data.
    lam_blocks = whole.lam * len(det.blocks) / whole.n_points
    mean_var_n = block_mean_variance(session.acc, det.blocks) / whole.nominal.scale ** 2
    grouping = group_blocks(means_n, mean_var_n, whole.theta_nominal, lam_blocks, settings.group)

    segments = []
    for i, (b0, b1) in enumerate(grouping.segments):
        blocks = det.blocks[b0:b1]
        if len(grouping.segments) == 1:
            acc_fit = whole
        else:
            acc_fit = calibrate_accelerometer(session.acc, blocks, acc_unit=session.acc_unit,
                                              g_in=g_in, g_out=g_out, settings=settings.acc,
                                              nominal=whole.nominal)
        gyro_fit = None
        if session.has_gyro:
            gyro_fit = calibrate_gyroscope(session.gyro, session.t_gyro, block_times[b0:b1],
                                           acc_fit.model.apply(det.means[b0:b1]),
                                           session.gyro_unit, settings.gyro,
                                           block_mean_cov(session.acc, blocks, acc_fit),
                                           saturated=gyro_sat)
        n_orient = distinct_orientations(det.means[b0:b1] - acc_fit.model.b)
        acc_cv = leave_one_block_out(acc_fit, det.means[b0:b1])
        seg = Segment(index=i, blocks=(b0, b1), t_start=float(block_times[b0, 0]),
                      t_end=float(block_times[b1 - 1, 1]), acc=acc_fit, gyro=gyro_fit,
                      orientations=n_orient, acc_cv=acc_cv)
        segments.append(seg)
        # A warning names its segment only when there are several: one segment is the session.
        where = i if len(grouping.segments) > 1 else None
        warnings += [w.in_segment(where) for w in acc_fit.warnings]
        if gyro_fit is not None:
            warnings += [w.in_segment(where) for w in gyro_fit.warnings]
        if acc_cv.overfitted:
            warnings.append(RunWarning(
                "acc_overfitted", f"overfitted: still blocks held out of the accelerometer fit "
                f"are off by {acc_cv.rms_mg:.3g} mg RMS against {acc_cv.in_sample_rms_mg:.3g} mg "
                f"for the blocks it saw; {acc_cv.advice()}", where))
        if n_orient < 9:
            warnings.append(RunWarning(
                "few_orientations", f"only {n_orient} distinct still orientations; 9 or more are "
                "needed to determine the accelerometer's 9 parameters without the prior (the "
                "regularisation holds the rest at nominal)", where))

    calibration = Calibration(
        segments=tuple(SegmentModels(t_start=s.t_start, t_end=s.t_end, acc=s.acc.model,
                                     gyro=s.gyro.model if s.gyro else None) for s in segments),
        acc_unit_raw=session.acc_unit, acc_unit=acc_unit, g=g_out,
        gyro_unit_raw=session.gyro_unit if session.has_gyro else None)
    calibrated = calibration.apply(session)
    quality = quality_figures(session, det, calibrated,
                              [s.gyro for s in segments if s.gyro is not None],
                              np.concatenate([s.acc_cv.block_error_mg for s in segments]),
                              g_in, g_out)
    return Result(session=session, settings=settings, detection=det, block_times=block_times,
                  whole=whole, grouping=grouping, segments=segments, calibration=calibration,
                  calibrated=calibrated, quality=quality, g_in=g_in, warnings=warnings)


def _drop_saturated(acc: np.ndarray, det: Detection) -> tuple[Detection, int]:
    if len(det.blocks) == 0:
        return det, 0
    bad = blocks_with(saturated_mask(acc), det.blocks)
    if not bad.any():
        return det, 0
    keep = ~bad
    return dataclasses.replace(det, blocks=det.blocks[keep], means=det.means[keep]), int(bad.sum())


def _check_blocks(session: Session, det: Detection, settings: Settings) -> None:
    n = len(det.blocks)
    if n >= 9:
        return
    still = float(np.mean(det.statistic < det.threshold))
    hint = ("nearly every sample looks still: was the device moved between poses?"
            if still > 0.9 else
            "few samples look still: lie the device down for longer, or raise the threshold "
            f"multiplier (now k = {settings.k:g})")
    raise ImucalError(f"found {n} static blocks of at least {det.min_len} samples; the "
                      f"accelerometer model needs 9 or more, from different orientations; {hint}",
                      source=session.source, field="static blocks")


__all__ = ["Result", "Segment", "Settings", "calibrate", "select_points", "make_nominal"]
