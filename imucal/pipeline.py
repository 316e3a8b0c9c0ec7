"""The one-way flow: detect -> group -> accelerometer -> gyroscope -> apply -> result."""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Sequence

import numpy as np

from imucal.errors import ImucalError, plural
from imucal.models import SensorModel, acc_model, acc_theta
from imucal.numerics.directions import distinct_orientations
from imucal.result import Result, Segment, Triad
from imucal.session import STANDARD_GRAVITY, Session, validate
from imucal.settings import Settings
from imucal.stages.accel import (
    AccFit,
    block_mean_cov,
    calibrate_accelerometer,
    make_nominal,
    select_points,
)
from imucal.stages.accel_cv import leave_one_block_out
from imucal.stages.apply import Calibration, MagModel, SegmentModels
from imucal.stages.apply_triads import (
    Combination,
    CombinedSpec,
    TriadCal,
    TriadsCalibration,
    main_names,
    matches,
)
from imucal.stages.combine import choose_low, clip_levels, found_clip
from imucal.stages.detect import Detection
from imucal.stages.detect_score import count_orientations
from imucal.stages.detect_tuning import tune_detector
from imucal.stages.drift import DriftTest, accelerometer_drift, gyroscope_drift
from imucal.stages.group import block_mean_variance, group_blocks
from imucal.stages.guide import ADVISED_HOLD_S, recording_guide
from imucal.stages.gyro import calibrate_gyroscope
from imucal.stages.mag import MagFit, MagUnfit, calibrate_magnetometer
from imucal.stages.mag_align import Turns
from imucal.stages.quality import quality_figures
from imucal.stages.sanity import (
    coverage_warning,
    gap_warnings,
    input_warning,
    split_at_gaps,
    turns_without_gyro,
    unwrap_session,
)
from imucal.stages.saturation import blocks_meeting, saturated_mask, saturated_runs
from imucal.stages.temperature import (
    MIN_SPAN_C,
    BiasPolynomial,
    block_legs,
    block_temperatures,
    fit_accel_bias_polynomial,
    fit_bias_polynomial,
    hysteresis,
)
from imucal.stages.temperature_judged import accel_drift, accel_figures, explained_note, gyro_drift
from imucal.stages.triads import (
    MIN_SHARED_BLOCKS,
    MIN_TURN_DEG,
    BlockMeans,
    GyroTurns,
    TriadModels,
    clock_offset,
    fit_against_reference,
    gyro_agreement,
    gyro_model_from,
    interval_means,
    triad_agreement,
    turn_rotvecs,
)
from imucal.stages.verdict import SegmentFigures, judge
from imucal.streams import Stream
from imucal.warning import RunWarning, calibrated_beside


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


def _detect(session: Session, settings: Settings, g_in: float) -> tuple[Detection, str | None]:
    """The still blocks (§1), and what became of the initial still period the file states.

    A logger's preamble may say how long the sensor lay still at the start: unless the user set
    the interval, the reference level of M1 is learned over it. A stated period that is not
    still (a wrong header) is said, and the detector chooses as if nothing were stated.
    """
    run = functools.partial(tune_detector, session.acc, session.t_acc, acc_unit=session.acc_unit,
                            g_in=g_in, source=session.source, rate=session.acc_rate)
    stated = session.init_still_s
    if stated is None or settings.detect.init is not None:
        return run(settings.detect), None
    said = f"the file states an initial still period of {stated:g} s"
    try:
        det = run(dataclasses.replace(settings.detect, init=(0.0, float(stated))))
    except ImucalError as e:
        if e.field != "initial still period":
            raise
        det = run(settings.detect)
        return det, (f"{said}, but the sensor is not still for that long at the start; the "
                     f"noise level was learned from {det.tuning.reference} instead")
    return det, f"{said}: the noise level was learned from {det.tuning.reference}"


def calibrate(session: Session, settings: Settings | None = None, **overrides) -> Result:
    """Calibrate a session: the whole method of method.md, one stage after the other."""
    try:
        settings = dataclasses.replace(settings or Settings(), **overrides)
    except TypeError as e:
        raise ImucalError(str(e), source="settings") from None
    validate(session)
    # How the input was read (units guessed, gaps bridged...): the loader's notes.
    warnings = [input_warning(note) for note in session.notes]
    # Faults that would otherwise calibrate wrongly without a word (stages/sanity.py).
    session, unwrapped = unwrap_session(session)
    warnings += unwrapped + gap_warnings(session)
    g_in, g_out, acc_unit = resolve_g(session, settings.g)

    still = _still_blocks(session, settings, g_in, warnings)  # §1
    det, block_times = still.det, still.block_times

    # A first whole-session fit: it gives the grouping calibrated magnitudes (method.md §2).
    whole = calibrate_accelerometer(session.acc, det.blocks, acc_unit=session.acc_unit,
                                    g_in=g_in, g_out=g_out, settings=settings.acc)
    means_n = whole.nominal.to_nominal(det.means)
    # The grouping fits block means, one point per block where M3 had n_points: scale lambda
    # so that the prior weighs the same against the data.
    lam_blocks = whole.lam * len(det.blocks) / whole.n_points
    mean_var_n = block_mean_variance(session.acc, det.blocks) / whole.nominal.scale ** 2
    grouping = group_blocks(means_n, mean_var_n, whole.theta_nominal, lam_blocks, settings.group)

    several = len(grouping.segments) > 1
    segments = []
    drifts: list[RunWarning] = []
    for i, (b0, b1) in enumerate(grouping.segments):  # §3 and §4 on each segment
        seg = _segment(session, settings, still, whole, i, b0, b1, g_in, g_out, several)
        segments.append(seg)
        # A warning names its segment only when there are several: one segment is the session.
        warnings += _segment_warnings(seg, seg.number if several else None)
        drifts += _drift_warnings(session, still, seg, seg.number if several else None)
    warnings += drifts

    calibration = Calibration(
        segments=tuple(SegmentModels(t_start=s.t_start, t_end=s.t_end, acc=s.acc.model,
                                     gyro=s.gyro.model if s.gyro else None) for s in segments),
        acc_unit_raw=session.acc_unit, acc_unit=acc_unit, g=g_out,
        gyro_unit_raw=session.gyro_unit if session.has_gyro else None)
    # The calibrated signals are never made whole here (at 6 h and 1 kHz they are 1 GB): the
    # figures read them a run of blocks or a chunk at a time, bit for bit the same rows
    # (Calibration.rows); Result.calibrated makes them on request.
    quality = quality_figures(session, det, functools.partial(calibration.rows, session, "acc"),
                              [s.gyro for s in segments if s.gyro is not None],
                              np.concatenate([s.acc_cv.block_error_mg for s in segments]),
                              g_in, g_out)  # §5
    gyro_rows = (functools.partial(calibration.rows, session, "gyro")
                 if calibration.applies_gyro(session) else None)
    up = np.concatenate([s.acc.model.apply(det.means[s.blocks[0]:s.blocks[1]])
                         for s in segments])
    guide = recording_guide(session, det, block_times, up,
                            [(s.blocks[0], s.gyro) for s in segments if s.gyro is not None],
                            gyro_rows)
    verdict = judge([SegmentFigures(s.number if several else None, s.acc_cv, s.gyro,
                                    s.orientations) for s in segments], guide, drifts)
    # the segments' blocks, in the order of ``up`` (the segments cover the blocks in order)
    seg_times = np.concatenate([block_times[s.blocks[0]:s.blocks[1]] for s in segments])
    magnetometer = _magnetometer(session, seg_times, up, warnings,
                                 functools.partial(_gyro_turns, session, segments, block_times),
                                 functools.partial(_up_moved, det.means, segments))
    if magnetometer is not None:  # Result.calibrated and --calibrated then hold mx, my, mz
        calibration = dataclasses.replace(calibration, mag=MagModel(
            M=magnetometer.M, b=magnetometer.b, unit=magnetometer.unit, field=magnetometer.field,
            R_am=np.eye(3) if magnetometer.R_am is None else magnetometer.R_am))
    return Result(session=session, settings=settings, detection=det, block_times=block_times,
                  whole=whole, grouping=grouping, segments=segments, calibration=calibration,
                  quality=quality, g_in=g_in, warnings=warnings, guide=guide, verdict=verdict,
                  magnetometer=magnetometer)


def _magnetometer(session: Session, block_times: np.ndarray, up: np.ndarray,
                  warnings: list[RunWarning], turns: Callable[[], Turns | None],
                  up_moved: Callable[[], np.ndarray]) -> MagFit | None:
    """The session's magnetometer (its first "mag" stream: the one ``--mag`` names is put
    first on load) calibrated over the whole session (M8, stages/mag.py), with the still
    blocks' calibrated gravity and the calibrated gyroscope's ``turns()`` between them
    (M8t) for its rotation to the accelerometer, the accelerometer's errors carried through
    (``up_moved()``); what it found said in ``warnings``. None
    without a magnetometer, or when it cannot be calibrated (said)."""
    stream = session.magnetometer
    if stream is None:
        return None
    try:
        fit = calibrate_magnetometer(stream, block_times, up, turns(), up_moved())
    except MagUnfit as e:
        if e.disturbances:
            warnings.append(RunWarning("mag_disturbed", "the magnetic field was not constant: "
                                       + "; ".join(d.text() for d in e.disturbances)))
        warnings.append(RunWarning("mag_not_calibrated", f"the magnetometer ({stream.name}) "
                                   f"is not calibrated: {e.message}"))
        return None
    warnings.extend(fit.warnings)
    return fit


def _gyro_turns(session: Session, segments: Sequence[Segment], block_times: np.ndarray
                ) -> Turns | None:
    """The turns between consecutive still blocks of each segment whose gyroscope is
    calibrated and determined, as M8t takes them: the blocks' indices in the order of the
    segments' blocks, each turn's rotation under the segment's M4 (M5's RK4, the
    gyroscope's own integrator) and again with each of M4's parameters moved by its standard
    error. Turns M4's fit left out (saturated, no data) are left out; None without any."""
    from imucal.stages.gyro_transitions import Transitions, gyro_model_of

    pairs, qs, moved = [], [], []
    offset = 0
    for s in segments:
        n = s.blocks[1] - s.blocks[0]
        g = s.gyro
        if g is not None and n > 1 and not g.undetermined and np.all(np.isfinite(g.std)):
            tr = Transitions(session.gyro, session.t_gyro, block_times[s.blocks[0]:s.blocks[1]])
            k = np.flatnonzero(~g.excluded)
            theta = g.report.theta
            # std is in raw units (gyro._standard_errors): back to the fit's own parameters
            scale = np.r_[np.ones(6), np.full(3, 1 / g.nominal_scale),
                          np.full(len(theta) - 9, g.nominal_scale)]
            models = [g.model] + [gyro_model_of(theta + d, g.static_bias, g.nominal_scale)
                                  for d in _gyro_error_steps(g.report.jac, g.std * scale)]
            q = tr.rotations_many(models)[:, k]
            pairs.append(np.column_stack([offset + k, offset + k + 1]))
            qs.append(q[0])
            moved.append(q[1:])
        offset += n
    if not pairs:
        return None
    width = max(len(m) for m in moved)
    if any(len(m) != width for m in moved):  # segments with and without a fitted bias
        moved = [np.concatenate([m, np.repeat(q[None], width - len(m), 0)])
                 for m, q in zip(moved, qs)]
    return Turns(np.concatenate(pairs), np.concatenate(qs), np.concatenate(moved, axis=1))


def _up_moved(means: np.ndarray, segments: Sequence[Segment]) -> np.ndarray:
    """(J, B, 3) the segments' calibrated still means (``up``'s rows) with each segment's M2
    moved by one of its error steps (:func:`_gyro_error_steps` of its covariance), the other
    segments' as fitted: the accelerometer's errors, for the magnetometer to carry through."""
    base = [s.acc.model.apply(means[s.blocks[0]:s.blocks[1]]) for s in segments]
    out = []
    for i, s in enumerate(segments):
        cov = np.asarray(s.acc.cov, float)
        if not np.all(np.isfinite(cov)):
            continue
        w, V = np.linalg.eigh((cov + cov.T) / 2)
        theta = acc_theta(s.acc.model)
        for d in (V * np.sqrt(np.maximum(w, 0.0))).T:
            moved = acc_model(theta + d).apply(means[s.blocks[0]:s.blocks[1]])
            out.append(np.concatenate(base[:i] + [moved] + base[i + 1:]))
    return np.array(out).reshape(len(out), -1, 3)


def _gyro_error_steps(jac: np.ndarray, std: np.ndarray) -> np.ndarray:
    """(p, p) steps of M4's parameters whose outer products sum to their covariance: the
    standard errors ``std`` the gyroscope's fit reports, with the correlations of its data
    Jacobian's normal matrix (the scales and misalignments of one axis pull together), as
    the principal axes scaled by their standard deviations."""
    d = 1.0 / np.maximum(np.linalg.norm(jac, axis=0), 1e-300)
    N = np.linalg.pinv((jac * d).T @ (jac * d))
    corr = N / np.sqrt(np.outer(np.diag(N), np.diag(N)))
    w, V = np.linalg.eigh(corr * np.outer(std, std))
    return (V * np.sqrt(np.maximum(w, 0.0))).T


@dataclasses.dataclass(frozen=True)
class StillBlocks:
    """The still blocks every later stage uses, and the gyroscope samples it must not trust."""

    det: Detection
    block_times: np.ndarray  # (B, 2) first and last still sample's time, s
    gyro_saturated: np.ndarray | None  # (M,) True where the gyroscope is flat at its limit


def _still_blocks(session: Session, settings: Settings, g_in: float,
                  warnings: list[RunWarning]) -> StillBlocks:
    """Detect the still blocks (§1), cut them at time gaps, drop those holding saturated
    samples, refuse too little still data; what was found is said in ``warnings``."""
    det, stated = _detect(session, settings, g_in)
    if det.note:  # the initial still interval was moved, or the reference level found (§1)
        warnings.append(RunWarning("detector_reference", det.note))
    if det.outlier_note:  # isolated absurd samples, left out of every still block (§1)
        warnings.append(RunWarning("acc_outliers", det.outlier_note))
    det = split_at_gaps(det, session.acc, session.t_acc)
    det, excluded = _drop_saturated(session.acc, det)
    if excluded:
        blocks = plural(excluded, 'static block')
        warnings.append(RunWarning("acc_saturated_blocks", f"excluded {blocks} "
                                   "holding saturated accelerometer samples (flat at the "
                                   "sensor's limit)"))
    _check_blocks(session, det, settings, g_in)
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
    if session.has_gyro and (no_gyro := coverage_warning(session, block_times)) is not None:
        warnings.append(no_gyro)
    if stated:
        warnings.append(RunWarning("init_still_stated", stated))
    return StillBlocks(det=det, block_times=block_times, gyro_saturated=gyro_sat)


def _segment(session: Session, settings: Settings, still: StillBlocks, whole: AccFit, i: int,
             b0: int, b1: int, g_in: float, g_out: float, several: bool) -> Segment:
    """One segment's accelerometer (§3, the whole-session fit when it is the only one) and
    gyroscope (§4) fits, with the held-out check of its accelerometer fit (§5)."""
    det, block_times = still.det, still.block_times
    blocks = det.blocks[b0:b1]
    acc_fit = whole
    if several:
        acc_fit = calibrate_accelerometer(session.acc, blocks, acc_unit=session.acc_unit,
                                          g_in=g_in, g_out=g_out, settings=settings.acc,
                                          nominal=whole.nominal)
    gyro_fit = None
    if session.has_gyro:
        gyro_fit = calibrate_gyroscope(session.gyro, session.t_gyro, block_times[b0:b1],
                                       acc_fit.model.apply(det.means[b0:b1]),
                                       session.gyro_unit, settings.gyro,
                                       block_mean_cov(session.acc, blocks, acc_fit),
                                       saturated=still.gyro_saturated, no_data=turns_without_gyro(
                                           session.t_gyro, block_times[b0:b1],
                                           session.gyro_step))
    return Segment(index=i, blocks=(b0, b1), t_start=float(block_times[b0, 0]),
                   t_end=float(block_times[b1 - 1, 1]), acc=acc_fit, gyro=gyro_fit,
                   orientations=distinct_orientations(det.means[b0:b1] - acc_fit.model.b),
                   acc_cv=leave_one_block_out(acc_fit, det.means[b0:b1]))


def _segment_warnings(seg: Segment, where: int | None) -> list[RunWarning]:
    """The fits' own warnings, overfitting (§5) and too few orientations, for one segment."""
    out = [w.in_segment(where) for w in seg.acc.warnings]
    if seg.gyro is not None:
        out += [w.in_segment(where) for w in seg.gyro.warnings]
    cv = seg.acc_cv
    if cv.overfitted:
        out.append(RunWarning(
            "acc_overfitted", f"overfitted: still blocks held out of the accelerometer fit "
            f"are off by {cv.rms_mg:.3g} mg RMS against {cv.in_sample_rms_mg:.3g} mg "
            f"for the blocks it saw; {cv.advice()}", where))
    if seg.orientations < 9:
        out.append(RunWarning(
            "few_orientations", f"only {seg.orientations} distinct still orientations; 9 or "
            "more determine the accelerometer's 9 parameters (with fewer, some are kept near "
            "their nominal values, not measured)", where))
    return out


def _drift_warnings(session: Session, still: StillBlocks, seg: Segment, where: int | None
                    ) -> list[RunWarning]:
    """A bias that moved within the segment (M7, stages/drift.py), said where it did."""
    b0, b1 = seg.blocks
    t_mid = still.block_times[b0:b1].mean(axis=1)
    tests = [accelerometer_drift(session.acc, still.det.blocks[b0:b1], still.det.means[b0:b1],
                                 t_mid, seg.acc)]
    if seg.gyro is not None:
        tests.append(gyroscope_drift(session.gyro, session.t_gyro, still.block_times[b0:b1],
                                     seg.gyro.model.K))
    return [w for t in tests if t is not None and (w := t.warning(where)) is not None]


def _drop_saturated(acc: np.ndarray, det: Detection) -> tuple[Detection, int]:
    if len(det.blocks) == 0:
        return det, 0
    bad = blocks_meeting(saturated_runs(acc), det.blocks)  # chunked: no mask of the signal
    if not bad.any():
        return det, 0
    keep = ~bad
    return dataclasses.replace(det, blocks=det.blocks[keep], means=det.means[keep]), int(bad.sum())


# Fewest distinct still orientations a calibration is attempted with: 6 (each face up and down)
# fix bias and scale, the prior holds the misalignment; 9 determine all of M2 (method.md §3).
MIN_ORIENTATIONS_FIT = 6


def _check_blocks(session: Session, det: Detection, settings: Settings, g_in: float) -> None:
    """Refuse too little still data, in one line naming the cause and what to record."""
    n = len(det.blocks)
    orient = count_orientations(det.means, session.acc_unit, g_in)
    if n >= 9 and orient >= MIN_ORIENTATIONS_FIT:
        return
    rate = 1.0 / float(np.median(np.diff(session.t_acc)))
    tun = det.tuning
    found = (f"found {plural(n, 'static block')} of at least {det.min_len} samples "
             f"({det.min_len / rate:.2g} s) in {orient} distinct orientation"
             f"{'' if orient == 1 else 's'}")
    still = float(np.sum(det.blocks[:, 1] - det.blocks[:, 0])) / len(session.acc)
    short = tun.short_holds if tun is not None else 0
    tried = ""
    if tun is not None and "k" in tun.tuned:
        ks = [c.k for c in tun.candidates]
        ws = sorted({c.window for c in tun.candidates}, reverse=True)
        tried = (f" (tried k = {min(ks):g}-{max(ks):g} and windows of "
                 f"{', '.join(str(w) for w in ws)} samples)")
    if n == 0 and short == 0:
        cause = (f"no still period at all{tried}: record still poses, each held motionless for "
                 "a few seconds, with the turns between them")
    elif orient <= 1 and still > 0.9:
        cause = ("nearly every sample looks still: was the device moved between poses? record "
                 "9 or more poses in different directions")
    elif short >= 9 - n and short > n:
        cause = (f"the holds are too short: {short} still stretches were shorter than the "
                 f"{tun.min_hold_s:.2g} s a block needs at the shortest window{tried}; hold "
                 f"each pose still for {ADVISED_HOLD_S:g} s or more")
    elif still < 0.5 and n < 9:
        hint = (f", or raise the threshold multiplier (now k = {det.k:g})"
                if settings.k is not None else tried)
        cause = (f"few samples look still ({still:.0%} in still blocks): lie the device still "
                 f"for a few seconds in each of 9 or more orientations{hint}")
    else:
        cause = (f"too few orientations: the accelerometer model needs 9 or more distinct "
                 f"still orientations ({MIN_ORIENTATIONS_FIT} at the least, the prior holding "
                 "the rest): record more poses, each face up and down and tilted between them")
    raise ImucalError(f"{found}; {cause}", source=session.source, field="static blocks")


__all__ = ["Result", "Segment", "Settings", "calibrate", "select_points", "make_nominal"]


# --- several triads in one device (method.md §11) -----------------------------------------------


def calibrate_triads(result: Result, which: Sequence[str] | str = "all",
                     temperature: bool = False) -> Result:
    """The run ``result`` with the session's other accelerometer triads (``Session.others``):
    each calibrated with the whole method on its own samples (with its own IMU's gyroscope where
    the session has one), and its rotation to ``result``'s triad, the reference, estimated from
    the reference's still blocks (M12, M13) with the triads' held-out agreement. ``which`` is
    ``"all"`` or the names of the triads to take (a stream's instance, its IMU, or its name). A
    triad that cannot be calibrated is said in its ``said``, never stops the run. With
    ``temperature``, each triad's bias in temperature too (:func:`calibrate_temperature`, on
    its own IMU's temperature stream)."""
    session, settings = result.session, result.settings
    accs = [s for s in session.others if s.kind == "acc"]
    if which != "all":
        wanted = [w.lower() for w in which]
        accs_named = [s for s in accs if {s.instance.lower(), (s.imu or "").lower(),
                                          s.name.lower()} & set(wanted)]
        missing = [w for w in wanted if not any(
            w in {s.instance.lower(), (s.imu or "").lower(), s.name.lower()} for s in accs)]
        if missing:
            have = ", ".join(s.instance for s in accs) or "none"
            raise ImucalError(f"no other accelerometer triad {missing[0]!r}; the session has: "
                              f"{have}", source=session.source, field="triads")
        accs = accs_named
    g_ref = result.calibration.g
    ref = interval_means(session.t_acc, functools.partial(result.calibration.rows, session, "acc"),
                         result.block_times, g_ref)
    raw = interval_means(session.t_acc, lambda a, b: session.acc[a:b], result.block_times, 1.0)
    ref = _with_temperature(result, ref, raw.means, result.block_times)
    ref_raw = result.whole.nominal.to_nominal(raw.means)
    ref_models = _triad_models(result, raw.means, result.block_times)
    ref_turns = _turns(result, session, result.block_times)
    triads = [_one_triad(session, settings, s, ref, ref_raw, ref_models, result.block_times,
                         temperature, ref_turns) for s in accs]
    warnings = list(result.warnings)
    for acc, tri in zip(accs, triads):  # the loader's "recorded, not calibrated" made true
        if tri.result is None:
            continue
        warnings = calibrated_beside(warnings, acc.instance, "calibrated as a triad of its "
                                     "own and turned to the reference (the triads section)")
        if tri.gyro is not None and tri.result.segments[0].gyro is not None:
            warnings = calibrated_beside(warnings, tri.gyro.split(" ", 1)[-1],
                                         f"calibrated with {acc.instance}, its IMU's "
                                         "accelerometer (the triads section)")
    return dataclasses.replace(result, triads=tuple(triads), warnings=warnings)


def _triad_models(result: Result, raw_means: np.ndarray, block_times: np.ndarray
                  ) -> TriadModels:
    """A run's accelerometer fits for the rotation's error (M13): each of the reference's
    blocks (``block_times``) in the segment whose span holds its middle, else the nearest."""
    mid = block_times.mean(axis=1)
    spans = np.array([[s.t_start, s.t_end] for s in result.segments])
    outside = np.maximum(spans[None, :, 0] - mid[:, None], mid[:, None] - spans[None, :, 1])
    covs = tuple(s.acc.cov for s in result.segments)
    fit = next((f for f in result.temperature if f.sensor == "accelerometer"), None)
    if fit is not None and fit.cov is not None and len(covs) == 1:
        # The constant fit's covariance holds the drift it could not model; M17's does not.
        covs = (fit.cov,)
    return TriadModels(raw_means=raw_means, segment_of_block=np.argmin(outside, axis=1),
                       params=tuple(s.acc.params for s in result.segments),
                       covs=covs, g=result.calibration.g)


def _one_triad(session: Session, settings: Settings, acc: Stream, ref: BlockMeans,
               ref_raw: np.ndarray, ref_models: TriadModels, block_times: np.ndarray,
               temperature: bool, ref_turns: GyroTurns | None) -> Triad:
    said: list[str] = []
    gyro = _gyro_partner(session, acc)
    sub = _triad_session(session, acc, gyro, said)
    sub, offset = _aligned(session, sub, acc.name, said)
    try:
        res = calibrate(sub, settings)
    except ImucalError as e:
        said.append(f"{acc.name} not calibrated: {e.problem}")
        return Triad(acc.name, gyro.name if gyro else None, None, None, tuple(said),
                     clock_offset_s=offset)
    if temperature:
        res = calibrate_temperature(res)
    if res.verdict is not None and not res.verdict.usable:
        said.append(f"{acc.name}: its own calibration is not usable ({res.verdict.reason})")
    other = interval_means(sub.t_acc, functools.partial(res.calibration.rows, sub, "acc"),
                           block_times, res.calibration.g, clipped=saturated_mask(sub.acc))
    raw = interval_means(sub.t_acc, lambda a, b: sub.acc[a:b], block_times, 1.0)
    other = _with_temperature(res, other, raw.means, block_times)
    other_raw = res.whole.nominal.to_nominal(raw.means)
    agreement = triad_agreement(ref, other, ref_raw, other_raw, ref_models,
                                _triad_models(res, raw.means, block_times))
    if agreement is None:
        said.append(f"{acc.name}: fewer than {MIN_SHARED_BLOCKS} of the reference's still blocks "
                    "in two directions hold its samples; its rotation to the reference is not "
                    "estimated")
    other_turns = _turns(res, sub, block_times)
    gyro_rot = None
    if gyro is not None:
        why = ("the reference has no calibrated gyroscope" if ref_turns is None
               else "its own gyroscope fit is missing" if other_turns is None else None)
        if why is None:
            gyro_rot = gyro_agreement(ref_turns, other_turns,
                                      None if agreement is None else agreement.rotation.R)
            if gyro_rot is None:
                why = (f"fewer than {MIN_SHARED_BLOCKS} turns of {MIN_TURN_DEG:g} deg or more "
                       "in two directions")
        if why is not None:
            said.append(f"{gyro.name}: calibrated with {acc.name}, in its own frame: {why}, so "
                        "its rotation to the reference's gyroscope is not estimated")
    against = None
    if agreement is not None:
        used = agreement.used
        fit = fit_against_reference(ref.means[used], raw.means[used],
                                    ref.var[used] + other.var[used])
        if fit is not None:  # in units of |g|: to the triad's own calibrated unit
            g = res.calibration.g
            against = dataclasses.replace(fit, model=SensorModel(
                T=fit.model.T, K=fit.model.K * g, b=fit.model.b), std_K=fit.std_K * g)
    return Triad(acc.name, gyro.name if gyro else None, res, agreement, tuple(said), gyro_rot,
                 against, offset)


# A clock offset below this many of the slower triad's sample steps (or 5 ms) is left alone.
OFFSET_STEPS = 2.0
MIN_OFFSET_CORRELATION = 0.5


def _aligned(session: Session, sub: Session, name: str,
             said: list[str]) -> tuple[Session, float | None]:
    """The triad's session on the reference's clock (method.md §11): the offset of its clock
    from the motion both saw (:func:`clock_offset`), its times moved by it where it exceeds a
    couple of sample steps, and said; None where the clocks could not be compared."""
    offset, corr = clock_offset(session.t_acc, session.acc, sub.t_acc, sub.acc)
    if not np.isfinite(offset) or corr < MIN_OFFSET_CORRELATION:
        if np.isfinite(offset):
            said.append(f"{name}: its clock could not be compared with the reference's (their "
                        f"motions correlate at {corr:.2f} at best): taken as the same clock")
        return sub, None
    limit = max(OFFSET_STEPS * max(session.acc_step, sub.acc_step), 0.005)
    if abs(offset) <= limit:
        return sub, offset
    said.append(f"{name}: its clock reads {abs(offset):.3f} s "
                f"{'ahead of' if offset > 0 else 'behind'} the reference's (from the motion "
                f"both saw, correlation {corr:.2f}): its times moved by {-offset:+.3f} s")
    moved = {"t_acc": sub.t_acc - offset}
    if sub.has_gyro:
        moved["t_gyro"] = sub.t_gyro - offset
    return dataclasses.replace(sub, **moved), offset


def _turns(result: Result, session: Session, block_times: np.ndarray) -> GyroTurns | None:
    """The turns between the reference's still blocks as ``result``'s calibrated gyroscope
    measures them (each turn with its segment's model; M14); None without a calibrated
    gyroscope or with fewer than two blocks."""
    segs = result.segments
    if not session.has_gyro or any(s.gyro is None for s in segs) or len(block_times) < 2:
        return None
    mid = (block_times[:-1, 1] + block_times[1:, 0]) / 2
    spans = np.array([[s.t_start, s.t_end] for s in segs])
    outside = np.maximum(spans[None, :, 0] - mid[:, None], mid[:, None] - spans[None, :, 1])
    which = np.argmin(outside, axis=1)
    params = tuple(s.gyro.params for s in segs)
    # std of the scales is relative to the nominal scale (gyro_model_of): in raw units here.
    stds = tuple(np.r_[s.gyro.std[:6], s.gyro.std[6:9] * s.gyro.nominal_scale] for s in segs)

    def turns(seg: int | None, p: np.ndarray | None) -> np.ndarray:
        models = [segs[i].gyro.model if i != seg else gyro_model_from(p, segs[i].gyro.model.b)
                  for i in range(len(segs))]
        M = np.array([models[i].matrix for i in which])
        b = np.array([models[i].b for i in which])
        return turn_rotvecs(session.gyro, session.t_gyro, block_times, M, b)

    return GyroTurns(turns=turns, params=params, stds=stds)


def _with_temperature(result: Result, means: BlockMeans, raw_means: np.ndarray,
                      block_times: np.ndarray) -> BlockMeans:
    """The calibrated block means with the bias at each block's temperature (M16) where the
    run fitted one for its accelerometer: a triad compared at the temperature it was at."""
    fit = next((f for f in result.temperature if f.sensor == "accelerometer"), None)
    stream = _temp_stream(result.session)
    if fit is None or fit.model is None or stream is None:
        return means
    temps = block_temperatures(stream.t, stream.values, block_times)
    ok = np.isfinite(temps) & np.isfinite(means.var)
    out = means.means.copy()
    out[ok] = fit.calibrated(raw_means[ok], temps[ok]) / result.calibration.g
    return dataclasses.replace(means, means=out)


def _temp_stream(session: Session) -> Stream | None:
    """The session's temperature stream: the one of the calibrated accelerometer's instance
    where there are several, else the first; None without one."""
    temps = [s for s in session.others if s.kind == "temp" and s.samples >= 2]
    if not temps:
        return None
    named = session.chosen[0].split(" ")[1] if session.chosen else None
    return next((s for s in temps if s.instance == named), temps[0])


def _gyro_partner(session: Session, acc: Stream) -> Stream | None:
    """The gyroscope of the accelerometer's IMU (a log's), or a table's g2x… beside a2x…."""
    gyros = [s for s in session.others if s.kind == "gyro"]
    if acc.imu is not None:
        same = [g for g in gyros if g.imu == acc.imu]
        if same:
            return same[0]
    if acc.instance[:1] == "a" and acc.instance[1:].isdigit():
        same = [g for g in gyros if g.instance == "g" + acc.instance[1:]]
        if same:
            return same[0]
    return None


def _triad_session(session: Session, acc: Stream, gyro: Stream | None,
                   said: list[str]) -> Session:
    """A Session of one triad's streams, calibrated like any other (units as the streams state
    them; one it does not state is that of the reference triad, and said)."""
    acc_unit = acc.unit
    if acc_unit is None:
        acc_unit = session.acc_unit
        said.append(f"{acc.name}: unit not stated, taken as the reference's ({acc_unit})")
    g_values, g_unit = None, None
    if gyro is not None:
        g_values, g_unit = gyro.values, gyro.unit
        if g_unit is None:
            g_unit = session.gyro_unit or "rad/s"
            said.append(f"{gyro.name}: unit not stated, taken as the reference's ({g_unit})")
        if g_unit == "deg/s":
            g_values, g_unit = np.radians(g_values), "rad/s"
    temps = tuple(s for s in session.others if s.kind == "temp" and (
        s.instance in (acc.instance, gyro.instance if gyro else None)
        or (s.imu is not None and s.imu in (acc.imu, gyro.imu if gyro else None))))
    device = [s for s in session.others if s.kind == "temp"]
    if not temps and len(device) == 1 and device[0].imu is None:
        temps = tuple(device)  # one thermometer of no IMU (a table's temp): the device's
    return Session(acc=acc.values, t_acc=acc.t, gyro=g_values, others=temps,
                   t_gyro=None if gyro is None else gyro.t, acc_unit=acc_unit,
                   gyro_unit=g_unit if gyro is not None else "rad/s",
                   source=f"{session.source} [{acc.name}]", sha256=session.sha256,
                   notes=acc.notes + (gyro.notes if gyro is not None else ()),
                   chosen=tuple(f"{s.name} ({s.origin})" for s in (acc, gyro) if s is not None))


# --- temperature (method.md §12) -----------------------------------------------------------------


def calibrate_temperature(result: Result) -> Result:
    """The run ``result`` with each sensor's bias a polynomial in temperature (M16, M17), from
    the session's temperature stream (the one of the calibrated accelerometer's instance where
    there are several), at each still block. A run the grouping (§2) split into segments is
    calibrated again as one segment first, and said: with a temperature stream a bias that
    drifts is the temperature's to explain. Without a temperature stream, or with too few
    blocks, nothing is fitted (``Result.temperature`` stays empty). Run it before
    :func:`calibrate_triads`, which fits each other triad's own with ``temperature=True``."""
    if result.triads:
        raise ValueError("calibrate_temperature comes before calibrate_triads (which takes "
                         "temperature=True for the other triads)")
    session = result.session
    temp = _temp_stream(session)
    if temp is None:
        return result
    said: tuple[str, ...] = ()
    if len(result.segments) > 1:
        said = (f"the grouping split the recording into {len(result.segments)} segments where "
                "the bias moved; with a temperature stream that drift is the temperature's, so "
                "it was calibrated again as one segment",)
        result = calibrate(session, dataclasses.replace(result.settings, single_segment=True))
    block_t = block_temperatures(temp.t, temp.values, result.block_times)
    det, fits = result.detection, []
    models = [seg.acc.model for seg in result.segments for _ in range(seg.n_blocks)]
    legs = block_legs(temp.t, temp.values, result.block_times)
    fits.append(fit_accel_bias_polynomial(block_t, det.means, models, result.calibration.g,
                                          legs))
    gyro_fit = result.segments[0].gyro
    if session.has_gyro and gyro_fit is not None:
        means = interval_means(session.t_gyro, lambda a, b: session.gyro[a:b],
                               result.block_times, 1.0).means
        fits.append(fit_bias_polynomial(block_t, means - gyro_fit.model.b, gyro_fit.model.b,
                                        "gyroscope", legs))
    unit = ("deg/s", 180 / np.pi) if session.gyro_unit == "rad/s" else ("counts", 1.0)
    out = []
    for f in fits:
        if f is None:
            continue
        if f.sensor == "gyroscope":  # the accelerometer's was fitted inside M17
            hyst = hysteresis(f, legs, *unit)
            f = dataclasses.replace(f, notes=f.notes + ((hyst,) if hyst else ()),
                                    hysteresis=hyst)
        out.append(dataclasses.replace(f, notes=said + f.notes))
    warnings = result.warnings
    if out:
        warnings = calibrated_beside(list(warnings), temp.instance, "each bias a polynomial "
                                     "in it (the temperature section)")
    return _judged_in_temperature(dataclasses.replace(result, temperature=tuple(out),
                                                      warnings=warnings),
                                  block_t, det.means, models, legs)


# What the verdict's figures are of once the accelerometer's bias is in temperature (§8).
IN_TEMPERATURE = "accelerometer with its bias in temperature (method.md M16)"


def _judged_in_temperature(result: Result, temps: np.ndarray, means: np.ndarray,
                           models: list[SensorModel], legs: np.ndarray,
                           drift: bool = True) -> Result:
    """The run judged as apply uses it (method.md §8, §12): the accelerometer's figures those
    of its bias in temperature (each still block held out of M17), the constant fit's kept
    beside them in the verdict's figures; and M7 asked of what each temperature model leaves,
    where its span (10 deg C or more) lets it explain a drift. One segment (as
    :func:`calibrate_temperature` leaves it); ``temps``, ``means``, ``models``, ``legs``: each
    block's temperature, raw mean, constant model and leg, as M17 was fitted to them (the
    run's blocks; with ``drift`` False, several sessions' pooled, whose times M7 cannot
    compare: their drift warnings stay the first run's)."""
    fits = {f.sensor: f for f in result.temperature}
    acc, gyro = fits.get("accelerometer"), fits.get("gyroscope")
    seg, session, det = result.segments[0], result.session, result.detection
    g, warnings = result.calibration.g, list(result.warnings)
    t_mid = result.block_times.mean(axis=1)
    acc_cv, words, constant = seg.acc_cv, "the fit", {}
    if acc is not None and acc.model is not None and acc.used is not None:
        acc, ratio = accel_figures(acc, temps, means, models, g, legs)
        scored = np.isfinite(acc.held_out_mg)  # a ramp's end blocks are not (§12)
        acc_cv = dataclasses.replace(seg.acc_cv, block_error_mg=acc.held_out_mg[scored],
                                     in_sample_error_mg=acc.after_mg, expected_ratio=ratio)
        words = "the fit in temperature"
        constant = {"acc_held_out_mg_constant": seg.acc_cv.rms_mg,
                    "acc_in_sample_mg_constant": seg.acc_cv.in_sample_rms_mg}
        if drift and acc.span_c >= MIN_SPAN_C:  # a shorter span explains no drift (§8)
            after = accel_drift(acc, means[acc.used], [models[i] for i in acc.used], g,
                                t_mid[acc.used],
                                block_mean_variance(session.acc, det.blocks[acc.used]))
            steady = accelerometer_drift(session.acc, det.blocks, det.means, t_mid, seg.acc)
            acc = _drift_judged(acc, warnings, "acc_bias_drift", steady, after)
    if drift and gyro is not None and seg.gyro is not None and gyro.used is not None \
            and gyro.span_c >= MIN_SPAN_C:
        k = seg.gyro.model.K
        after = gyro_drift(gyro, session.gyro, session.t_gyro, result.block_times, k)
        steady = gyroscope_drift(session.gyro, session.t_gyro, result.block_times, k)
        gyro = _drift_judged(gyro, warnings, "gyro_bias_drift", steady, after)
    drifts = [w for w in warnings if w.code in ("acc_bias_drift", "gyro_bias_drift")]
    verdict = judge([SegmentFigures(None, acc_cv, seg.gyro, seg.orientations, words)],
                    result.guide, drifts, model=IN_TEMPERATURE if constant else None)
    verdict = dataclasses.replace(verdict, figures=verdict.figures | constant)
    judged = {f.sensor: f for f in (acc, gyro) if f is not None}
    return dataclasses.replace(result, warnings=warnings, verdict=verdict,
                               temperature=tuple(judged.get(f.sensor, f)
                                                 for f in result.temperature))


def _drift_judged(fit: BiasPolynomial, warnings: list[RunWarning], code: str,
                  steady: DriftTest | None, after: DriftTest | None) -> BiasPolynomial:
    """M7's warning ``code`` in ``warnings`` (in place) replaced by the test of what the
    temperature model leaves (``after``; a steady bias's test, ``steady``, where none could be
    made), and ``fit`` with a note of what the temperature did to a drift found."""
    if after is None:
        return fit
    i = next((j for j, w in enumerate(warnings) if w.code == code), None)
    new = after.warning(None)
    if i is not None:
        del warnings[i]
    if new is not None:
        warnings.insert(len(warnings) if i is None else i, new)
    if steady is not None and steady.drifting:
        return dataclasses.replace(fit, notes=fit.notes + (explained_note(fit.sensor, steady,
                                                                          after),))
    return fit


def calibrate_same_device(results: Sequence[Result]) -> Result:
    """The first run with each sensor's bias in temperature (M16, M17) fitted to the still
    blocks of every run, sessions of one device recorded at different temperatures
    (``--same-device``): the blocks pooled at their own temperatures, linearised at the first
    run's M2. Each session must hold a temperature stream, and all the same raw units."""
    first = results[0]
    if first.triads:
        raise ValueError("calibrate_same_device comes before calibrate_triads")
    temps, means, gyro, models, legs = [], [], [], [], []
    acc_model0 = first.segments[0].acc.model
    gyro_fit = first.segments[0].gyro
    for r in results:
        s = r.session
        stream = _temp_stream(s)
        if stream is None:
            raise ImucalError("--same-device: the session holds no temperature stream (a temp "
                              "column, or a log's)", source=s.source, field="temperature")
        if s.acc_unit != first.session.acc_unit or s.gyro_unit != first.session.gyro_unit:
            raise ImucalError(f"--same-device: units {s.acc_unit}, {s.gyro_unit} differ from "
                              f"the first session's ({first.session.acc_unit}, "
                              f"{first.session.gyro_unit})", source=s.source, field="units")
        temps.append(block_temperatures(stream.t, stream.values, r.block_times))
        legs.append(block_legs(stream.t, stream.values, r.block_times))
        means.append(r.detection.means)
        models += [acc_model0] * len(r.detection.blocks)
        if gyro_fit is not None and s.has_gyro:
            gyro.append(interval_means(s.t_gyro, lambda a, b, s=s: s.gyro[a:b], r.block_times,
                                       1.0).means)
    block_t = np.concatenate(temps)
    fits = [fit_accel_bias_polynomial(block_t, np.concatenate(means), models,
                                      first.calibration.g, np.concatenate(legs))]
    if gyro_fit is not None and len(gyro) == len(results):
        fits.append(fit_bias_polynomial(block_t, np.concatenate(gyro) - gyro_fit.model.b,
                                        gyro_fit.model.b, "gyroscope", np.concatenate(legs)))
    levels = ", ".join(f"{float(np.nanmean(t)):.1f}" for t in temps)
    said = (f"from {len(results)} sessions of one device at {levels} deg C (their still poses "
            "pooled, each at its own temperature)",)
    out = tuple(dataclasses.replace(f, notes=said + f.notes) for f in fits if f is not None)
    warnings = first.warnings
    if out:
        warnings = calibrated_beside(list(warnings), _temp_stream(first.session).instance,
                                     "each bias a polynomial in it, with the other sessions' "
                                     "(the temperature section)")
    result = dataclasses.replace(first, temperature=out, warnings=warnings)
    if len(first.segments) > 1:  # apply keeps the constant fit's segments: judged as they are
        return result
    return _judged_in_temperature(result, block_t, np.concatenate(means), models,
                                  np.concatenate(legs), drift=False)


# --- the triads as one calibration to apply; a low-range and a high-range pair (M18) ------------


def triads_calibration(result: Result) -> TriadsCalibration:
    """The run's triads as applying them needs (method.md §11, §12): the reference's models and
    temperature fits first, then each other triad calibrated and turned to the reference (one
    without a rotation to it is left out), its times moved as the run moved them."""
    def temps(r: Result) -> dict:
        return {f.sensor: f for f in r.temperature}

    ref_t = temps(result)
    acc_name, gyro_name = main_names(result.session)
    out = [TriadCal(name=acc_name, gyro=gyro_name, calibration=result.calibration, R=np.eye(3),
                    acc_temp=ref_t.get("accelerometer"), gyro_temp=ref_t.get("gyroscope"))]
    for tri in result.triads:
        if tri.result is None or tri.agreement is None:
            continue
        t = temps(tri.result)
        stream = next(s for s in result.session.others if s.name == tri.name)
        out.append(TriadCal(name=tri.name, gyro=tri.gyro, calibration=tri.result.calibration,
                            R=tri.agreement.rotation.R, acc_temp=t.get("accelerometer"),
                            gyro_temp=t.get("gyroscope"),
                            time_shift=float(stream.t[0] - tri.result.session.t_acc[0])))
    combined = None if result.combined is None else result.combined.spec
    return TriadsCalibration(triads=tuple(out), combined=combined)


def combine_triads(result: Result, ranges: dict[str, float] | None = None) -> Result:
    """The run with its low-range and high-range accelerometers combined (M18) where the
    reference and one other triad are such a pair: which is which from ``ranges`` (g, by triad
    name) or from the one that clips, the low-range one's clip levels, the high-range one's
    noise in the still blocks, and the step at the switch measured on this session."""
    ranges = dict(ranges or {})
    session = result.session
    cal = triads_calibration(result)
    names = [tc.name for tc in cal.triads]
    for wanted in ranges:
        if not any(matches(tc.name, _imu_of(session, tc.name), wanted) for tc in cal.triads):
            raise ImucalError(f"no calibrated accelerometer triad {wanted!r}; there are: "
                              f"{', '.join(n.split(' ', 1)[1] for n in names)}",
                              source=session.source, field="--range")
    if len(cal.triads) != 2:
        if ranges:
            raise ImucalError(f"--range combines a pair of accelerometer triads; {len(cal.triads)} "
                              "are calibrated and turned to the reference", source=session.source,
                              field="--range")
        return result
    subs = [session] + [next(t for t in result.triads if t.name == names[1]).result.session]
    stated = tuple(next((g for w, g in ranges.items()
                         if matches(n, _imu_of(session, n), w)), None) for n in names)
    choice = choose_low(tuple(names), tuple(s.acc for s in subs), tuple(s.acc_unit for s in subs),
                        stated)
    if choice.low is None:
        if ranges or any(np.isfinite(found_clip(s.acc)[k]).any() for s in subs for k in (0, 1)):
            return dataclasses.replace(result, combined=Combination(None, None, (choice.why,)))
        return result
    low, high = choice.low, 1 - choice.low
    levels = clip_levels(subs[low].acc, subs[low].acc_unit, stated[low])
    if levels is None:
        return dataclasses.replace(result, combined=Combination(None, None, (
            f"{names[low]}: its range is not known (no clipped sample, none stated with --range "
            "NAME=G) and the raw unit has no level in g: not combined",)))
    high_cal = cal.triads[high].calibration
    noise = interval_means(subs[high].t_acc, functools.partial(high_cal.rows, subs[high], "acc"),
                           result.block_times, high_cal.g)
    per_sample = noise.var * noise.counts
    noise_mg = float(np.sqrt(np.nanmedian(per_sample))) * 1e3 if np.isfinite(
        per_sample).any() else None
    spec = CombinedSpec(low=names[low], high=names[high], levels=levels, high_noise_mg=noise_mg)
    applied = dataclasses.replace(cal, combined=spec).apply(session)
    said = (f"{choice.why}: {names[low]} is the low-range triad (limits "
            f"{levels.how}), {names[high]} the high-range one",
            *(n for n in applied.notes if n.startswith("combined accelerometer")))
    return dataclasses.replace(result, combined=Combination(spec, applied.step, said))


def _imu_of(session: Session, name: str) -> str | None:
    stream = next((s for s in session.others if s.name == name), None)
    return None if stream is None else stream.imu
