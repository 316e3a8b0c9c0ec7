"""An :class:`imucal.Result` as one Rerun recording (``.rrd``), layout included.

Everything is logged column-wise (``send_columns``, chunks of at most ``CHUNK_ROWS`` rows),
never sample by sample. The paths below are a contract: scripts read them back
(:mod:`viewer.readback`); the constants live in :mod:`viewer.paths`.

Timelines: ``time`` (duration, seconds on the session's clock), ``lambda`` (sequence: index
into the whole-session fit's lambda grid), ``iteration`` (sequence: accepted optimiser step,
0 = the start point). "static" rows carry no time and hold at every time.

=========================================== ========== ============================================
Entity path                                  Timeline   Content
=========================================== ========== ============================================
imu/accelerometer/magnitude                  time       Scalars [raw, calibrated], calibrated unit
                                                        (g or m/s^2), every sample. "raw" is
                                                        ``|a_raw|`` through the fit's nominal frame:
                                                        the raw signal itself for input in g or
                                                        m/s^2; offset and scale of the sphere fit
                                                        for raw counts.
imu/accelerometer/raw                        time       Scalars [x, y, z], raw unit (*)
imu/accelerometer/calibrated                 time       Scalars [x, y, z], calibrated unit (*)
imu/gyroscope/magnitude                      time       Scalars [raw, calibrated], rad/s, every
                                                        sample. "raw" is ``|w_raw|`` for input in
                                                        rad/s; for raw counts ``|w_raw - b_g|``
                                                        times the nominal scale (first segment)
imu/gyroscope/raw                            time       Scalars [x, y, z], raw unit (*)
imu/gyroscope/calibrated                     time       Scalars [x, y, z], rad/s (*)
detector/statistic                           time       Scalars log10 s2 (M1) (*)
detector/threshold                           time       Scalars log10 (k s2_init), 2 rows
detector/blocks                              time       StateChange "still" at each block's first
                                                        sample, reset at its last
detector/segments                            time       StateChange "segment i", "between
                                                        segments" (mean of neighbours' parameters)
blocks/norm_error_mg/before | after          time       Scalars ``|mean a| / g - 1`` in mg, one
                                                        row per static block at its middle
gravity/axes                                 static     Arrows3D body x, y, z
gravity/measured                             time       Arrows3D unit gravity u_k of static block k
                                                        (mean calibrated acceleration), logged at
                                                        the block's first sample
gravity/previous                             time       Arrows3D u_(k-1), logged at block k (k > 0
                                                        within a segment)
gravity/predicted_before | predicted_after   time       Arrows3D ``R_k^T u_(k-1)`` (M5) with the raw
                                                        (nominal) / the calibrated gyroscope, at
                                                        block k (k > 0); drawn 1.24 / 1.12 long so
                                                        they do not hide in the measured arrow:
                                                        the direction is ``v / |v|``
gravity_angle/before | after                 time       Scalars angle u_k to the prediction, deg,
                                                        at block k (k > 0)
lcurve/points | line                         static     Points2D (labels: lambda, left blank where
                                                        points crowd; AnyValues ``lambda``: every
                                                        point's) / LineStrips2D at (log10 rho,
                                                        -log10 eta) of the whole-session fit: y is
                                                        negated so larger eta is drawn higher (2D
                                                        views draw y downwards)
lcurve/corner                                static     Points2D + AnyValues(lambda, index,
                                                        residual_norm, solution_norm)
lcurve/frame                                 static     axes and decade tick labels
lcurve/segment_<i>/points | line | corner    static     each segment's own L-curve (only with more
                                                        than one segment)
lambda/log10_lambda                          lambda     Scalars
lambda/static_norm_rms_mg | static_norm_max_mg lambda   Scalars RMS / max over static blocks of
                                                        ``|mean a| / g - 1`` (mg) with the
                                                        parameters solved at that lambda
lambda/chosen                                lambda     Scalars static_norm_rms_mg, one row at the
                                                        L-curve corner
lambda/log10_residual_norm | solution_norm   lambda     Scalars
lambda/accelerometer/misalignment|scale|bias lambda     Scalars [3] each, raw-unit parameters
iteration/<fit>/<sensor>/log10_cost          iteration  Scalars; <fit> = segment_<i> (and
                                                        ``whole`` when the first whole-session fit
                                                        is not segment 0's), <sensor> =
                                                        accelerometer | gyroscope
iteration/<fit>/<sensor>/misalignment|scale|bias iteration Scalars, raw-unit parameters at
                                                        each accepted step (gyroscope:
                                                        misalignment has 6 angles)
calibration/summary                          static     TextDocument (markdown): parameters with
                                                        standard errors, quality, warnings
calibration/segment_<i>/accelerometer        static     AnyValues: T (9, row-major), K, b, params,
                                                        std, param_names, lambda, t_start, t_end,
                                                        start, cost_start, cost_end, n_points,
                                                        n_blocks, orientations
calibration/segment_<i>/gyroscope            static     AnyValues: T, K, b, params, std,
                                                        param_names, lambda, bias_source,
                                                        nominal_scale, transitions,
                                                        transitions_excluded, cost_start,
                                                        cost_end
calibration/quality                          static     AnyValues: static_norm_rms_mg_before|after,
                                                        sample_norm_rms_mg_before|after,
                                                        gravity_angle_rms_deg_before|after (NaN
                                                        where not defined), block_norm_error_mg
calibration/info                             static     AnyValues: source, sha256, units, g,
                                                        lambda, n_blocks, n_segments, grouping,
                                                        settings (JSON), warnings
=========================================== ========== ============================================

(*) Signals longer than ``DECIMATE_ABOVE`` samples are logged as a min/max envelope of at most
``ENVELOPE_ROWS`` rows (:mod:`viewer.decimate`: every peak kept, drawn at most one bucket from
where it happened). The magnitudes are logged at full rate, except that a long signal's
stretches between still blocks become such an envelope too (the still blocks stay at full rate).

The gyroscope entities exist only for a session with a gyroscope; the L-curve and ``lambda``
entities only when lambda was chosen by the L-curve (not fixed).
"""

from __future__ import annotations

import json
import math
import os
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO

import numpy as np
import rerun as rr

from imucal.io.atomic import atomic_path
from imucal.models import ACC_PARAM_NAMES, GYRO_PARAM_NAMES, acc_theta, gyro_theta

from . import paths as P
from .decimate import detail_envelope, envelope

if TYPE_CHECKING:
    from imucal.result import Result
    from imucal.stages.accel import AccFit, LCurve
    from imucal.stages.gyro import GyroFit

CHUNK_ROWS = 100_000
DECIMATE_ABOVE = 200_000
ENVELOPE_ROWS = 100_000

# Colours (RGBA)
RAW = 0xFF7F0EFF
CALIBRATED = 0x1F77B4FF
MEASURED = 0x2CA02CFF
BEFORE = 0xD62728FF
AFTER = 0x1F77B4FF
PREVIOUS = 0x9E9E9EFF
XYZ = [0xE15759FF, 0x59A14FFF, 0x4E79A7FF]
STILL = 0x59A14FFF
SEGMENT_COLORS = [0x4E79A7FF, 0xF28E2BFF, 0x76B7B2FF, 0xB07AA1FF, 0xEDC948FF, 0xFF9DA7FF]
BETWEEN = 0xBAB0ACFF
CORNER = 0xD62728FF
ARROW_AFTER = 1.12  # drawn lengths of the predicted gravity arrows (the measured one: 1)
ARROW_BEFORE = 1.24


# --- small mappings the core does not (yet) provide ----------------------------------------------


def gyro_nominal(result: Result) -> np.ndarray:
    """The raw gyroscope in nominal rad/s, for plotting beside the calibrated one: the signal
    itself for input in rad/s; for raw counts (which carry an ADC offset) minus the first
    segment's static bias, times its nominal scale."""
    s, fit = result.session, result.segments[0].gyro
    if s.gyro_unit != "counts" or fit is None:
        return s.gyro
    return (s.gyro - fit.model.b) * fit.nominal_scale


def block_norm_errors_mg(fit: AccFit, means_raw: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """``|mean a| / g - 1`` in mg of each static block under the solution ``theta`` (nominal
    frame): the calibration is affine, so calibrating the raw block mean equals averaging the
    calibrated samples."""
    a = fit.model_for(theta).apply(means_raw)
    return (np.linalg.norm(a, axis=1) / fit.g_out - 1.0) * 1e3


# --- logging helpers -----------------------------------------------------------------------------


def _chunks(n: int, size: int = CHUNK_ROWS) -> Iterator[slice]:
    for i in range(0, n, size):
        yield slice(i, min(i + size, n))


def _send_scalars(rec: rr.RecordingStream, path: str, index: np.ndarray, values: np.ndarray,
                  timeline: str = P.TIME) -> int:
    """Scalars (one per row, or k per row for (N, k) values) in chunks; returns rows sent."""
    values = np.asarray(values, dtype=np.float64)
    index = np.asarray(index)
    for s in _chunks(len(index)):
        if timeline == P.TIME:
            col = rr.TimeColumn(timeline, duration=index[s])
        else:
            col = rr.TimeColumn(timeline, sequence=index[s])
        rec.send_columns(path, indexes=[col], columns=rr.Scalars.columns(scalars=values[s]))
    return len(index)


def _rgba(colors: list[int]) -> np.ndarray:
    """0xRRGGBBAA values as the unambiguous array Rerun wants (3 ints could be one RGB)."""
    return np.asarray(colors, dtype=np.uint32)


def _style_lines(rec: rr.RecordingStream, path: str, names: list[str], colors: list[int],
                 width: float | None = None) -> None:
    widths = None if width is None else [width] * len(names)
    rec.log(path, rr.SeriesLines(names=names, colors=_rgba(colors), widths=widths), static=True)


def _style_points(rec: rr.RecordingStream, path: str, names: list[str], colors: list[int],
                  size: float = 4.0, marker: str = "circle") -> None:
    rec.log(path, rr.SeriesPoints(names=names, colors=_rgba(colors), markers=[marker] * len(names),
                                  marker_sizes=[size] * len(names)), static=True)


def _log10(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(x > 0, np.log10(np.where(x > 0, x, 1.0)), np.nan)


def _nan(x: float | None) -> float:
    return float("nan") if x is None else float(x)


# --- the recording -------------------------------------------------------------------------------


def log_result(result: Result, rec: rr.RecordingStream) -> dict[str, int]:
    """Log everything the viewer shows about ``result`` to ``rec``.

    Returns the number of rows logged per temporal entity (what a test compares the file with).
    """
    rows: dict[str, int] = {}
    _log_signals(result, rec, rows)
    _log_detector(result, rec, rows)
    _log_blocks(result, rec, rows)
    _log_gravity(result, rec, rows)
    _log_lcurves(result, rec, rows)
    _log_iterations(result, rec, rows)
    _log_results(result, rec)
    return rows


def _log_signals(result: Result, rec: rr.RecordingStream, rows: dict[str, int]) -> None:
    s, cal = result.session, result.calibrated
    unit = cal.acc_unit
    raw_mag = np.linalg.norm(result.whole.nominal.to_nominal(s.acc), axis=1) * result.whole.g_out
    still = np.zeros(len(s.t_acc), bool)
    still[_block_samples(result.detection.blocks)] = True
    t, v = _magnitudes(s.t_acc, np.column_stack([raw_mag, cal.acc_norm]), still)
    rows[P.ACC_MAGNITUDE] = _send_scalars(rec, P.ACC_MAGNITUDE, t, v)
    _style_lines(rec, P.ACC_MAGNITUDE, [f"raw |a| ({unit}, nominal)", f"calibrated |a| ({unit})"],
                 [RAW, CALIBRATED])
    for path, x, label in ((P.ACC_RAW, s.acc, s.acc_unit), (P.ACC_CALIBRATED, cal.acc, unit)):
        t, v = envelope(s.t_acc, x, ENVELOPE_ROWS) if len(x) > DECIMATE_ABOVE else (s.t_acc, x)
        rows[path] = _send_scalars(rec, path, t, v)
        _style_lines(rec, path, [f"{c} ({label})" for c in "xyz"], XYZ)

    if not s.has_gyro or cal.gyro is None:
        return
    raw_mag = np.linalg.norm(gyro_nominal(result), axis=1)
    bt = result.block_times
    lo = np.searchsorted(s.t_gyro, bt[:, 0], side="left")
    hi = np.searchsorted(s.t_gyro, bt[:, 1], side="right")
    still = np.zeros(len(s.t_gyro), bool)
    still[_block_samples(np.column_stack([lo, hi]))] = True
    t, v = _magnitudes(s.t_gyro, np.column_stack([raw_mag, cal.gyro_norm]), still)
    rows[P.GYRO_MAGNITUDE] = _send_scalars(rec, P.GYRO_MAGNITUDE, t, v)
    _style_lines(rec, P.GYRO_MAGNITUDE, ["raw |w| (rad/s, nominal)", "calibrated |w| (rad/s)"],
                 [RAW, CALIBRATED])
    for path, x, label in ((P.GYRO_RAW, s.gyro, s.gyro_unit), (P.GYRO_CALIBRATED, cal.gyro,
                                                                "rad/s")):
        t, v = (envelope(s.t_gyro, x, ENVELOPE_ROWS) if len(x) > DECIMATE_ABOVE
                else (s.t_gyro, x))
        rows[path] = _send_scalars(rec, path, t, v)
        _style_lines(rec, path, [f"{c} ({label})" for c in "xyz"], XYZ)


def _block_samples(blocks: np.ndarray) -> np.ndarray:
    """Indices of the samples of [start, end) blocks (one vector operation)."""
    blocks = np.asarray(blocks, np.int64).reshape(-1, 2)
    lengths = np.maximum(blocks[:, 1] - blocks[:, 0], 0)
    offsets = np.repeat(blocks[:, 0] - np.cumsum(lengths) + lengths, lengths)
    return offsets + np.arange(int(lengths.sum()))


def _magnitudes(t: np.ndarray, v: np.ndarray, still: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """A long signal's magnitudes: full rate in the still blocks, where the calibration is
    judged to the milli-g, and a min/max envelope in between, where only the swings matter."""
    if len(t) <= DECIMATE_ABOVE:
        return t, v
    return detail_envelope(t, v, still, ENVELOPE_ROWS)


def _log_detector(result: Result, rec: rr.RecordingStream, rows: dict[str, int]) -> None:
    det, t = result.detection, result.session.t_acc
    stat = _log10(det.statistic)
    ts, vs = envelope(t, stat, ENVELOPE_ROWS) if len(stat) > DECIMATE_ABOVE else (t, stat)
    rows[P.DETECTOR_STATISTIC] = _send_scalars(rec, P.DETECTOR_STATISTIC, ts, vs)
    _style_lines(rec, P.DETECTOR_STATISTIC, ["log10 s2 (M1)"], [0x4E79A7FF])
    rows[P.DETECTOR_THRESHOLD] = _send_scalars(rec, P.DETECTOR_THRESHOLD, [t[0], t[-1]],
                                               np.full(2, _log10(det.threshold)))
    _style_lines(rec, P.DETECTOR_THRESHOLD, [f"log10 threshold (k = {result.settings.k:g})"],
                 [BEFORE], width=2.0)

    bt = result.block_times
    times = np.column_stack([bt[:, 0], bt[:, 1]]).ravel()
    states = ["still", ""] * len(bt)
    rec.log(P.DETECTOR_BLOCKS, rr.StateConfiguration(values=["still"], labels=["still"],
                                                     colors=_rgba([STILL])), static=True)
    rec.send_columns(P.DETECTOR_BLOCKS, indexes=[rr.TimeColumn(P.TIME, duration=times)],
                     columns=rr.StateChange.columns(state=states))
    rows[P.DETECTOR_BLOCKS] = len(times)

    seg_t, seg_s = [], []
    names = [f"segment {i}" for i in range(len(result.segments))]
    for i, seg in enumerate(result.segments):
        seg_t.append(seg.t_start)
        seg_s.append(names[i])
        if i + 1 < len(result.segments):
            seg_t.append(seg.t_end)
            seg_s.append("between segments")
    seg_t.append(result.segments[-1].t_end)
    seg_s.append("")
    colors = [SEGMENT_COLORS[i % len(SEGMENT_COLORS)] for i in range(len(names))]
    rec.log(P.DETECTOR_SEGMENTS, rr.StateConfiguration(
        values=[*names, "between segments"],
        labels=[*names, "between segments (mean of neighbours)"],
        colors=_rgba([*colors, BETWEEN])), static=True)
    rec.send_columns(P.DETECTOR_SEGMENTS, indexes=[rr.TimeColumn(P.TIME, duration=seg_t)],
                     columns=rr.StateChange.columns(state=seg_s))
    rows[P.DETECTOR_SEGMENTS] = len(seg_t)


def _log_blocks(result: Result, rec: rr.RecordingStream, rows: dict[str, int]) -> None:
    q = result.quality
    mid = result.block_times.mean(axis=1)
    if q.block_norm_error_before_mg is not None:
        rows[P.BLOCK_ERROR_BEFORE] = _send_scalars(rec, P.BLOCK_ERROR_BEFORE, mid,
                                                   q.block_norm_error_before_mg)
        _style_points(rec, P.BLOCK_ERROR_BEFORE, ["before (mg)"], [BEFORE])
    rows[P.BLOCK_ERROR_AFTER] = _send_scalars(rec, P.BLOCK_ERROR_AFTER, mid,
                                              q.block_norm_error_mg)
    _style_points(rec, P.BLOCK_ERROR_AFTER, ["after (mg)"], [AFTER])


def _log_gravity(result: Result, rec: rr.RecordingStream, rows: dict[str, int]) -> None:
    """Per segment, block k's measured gravity at its first sample; for k > 0 also the one
    carried over from block k-1 by the raw and the calibrated gyroscope, and the angles."""
    segs = [s for s in result.segments if s.gyro is not None and len(s.gyro.u_meas)]
    if not segs:
        return
    starts = result.block_times[:, 0]
    t_meas = np.concatenate([starts[s.blocks[0]:s.blocks[1]] for s in segs])
    meas = np.concatenate([np.vstack([s.gyro.u_prev[:1], s.gyro.u_meas]) for s in segs])
    t = np.concatenate([starts[s.blocks[0] + 1:s.blocks[1]] for s in segs])
    fits = [s.gyro for s in segs]
    # path: (times, unit vectors, drawn length, colour, radius). The predictions nearly
    # coincide with the measured direction: drawn longer and thinner, their tips stay visible.
    arrows = {
        P.GRAVITY_MEASURED: (t_meas, meas, 1.0, MEASURED, 0.025),
        P.GRAVITY_PREVIOUS: (t, np.concatenate([f.u_prev for f in fits]), 1.0, PREVIOUS, 0.015),
        P.GRAVITY_PREDICTED_AFTER: (t, np.concatenate([f.u_pred_after for f in fits]),
                                    ARROW_AFTER, AFTER, 0.012),
    }
    have_before = all(f.u_pred_before is not None for f in fits)
    if have_before:
        arrows[P.GRAVITY_PREDICTED_BEFORE] = (
            t, np.concatenate([f.u_pred_before for f in fits]), ARROW_BEFORE, BEFORE, 0.012)
    rec.log(P.GRAVITY_AXES, rr.Arrows3D(vectors=np.eye(3) * 1.2, colors=_rgba(XYZ),
                                        labels=["x", "y", "z"], radii=0.006), static=True)
    for path, (tt, v, length, color, radius) in arrows.items():
        n = len(tt)
        rec.send_columns(path, indexes=[rr.TimeColumn(P.TIME, duration=tt)],
                         columns=rr.Arrows3D.columns(vectors=v * length,
                                                     colors=_rgba([color] * n),
                                                     radii=[radius] * n))
        rows[path] = n

    after = np.concatenate([f.angle_after for f in fits])
    rows[P.GRAVITY_ANGLE_AFTER] = _send_scalars(rec, P.GRAVITY_ANGLE_AFTER, t, after)
    _style_points(rec, P.GRAVITY_ANGLE_AFTER, ["after: calibrated gyro (deg)"], [AFTER])
    if have_before:
        before = np.concatenate([f.angle_before for f in fits])
        rows[P.GRAVITY_ANGLE_BEFORE] = _send_scalars(rec, P.GRAVITY_ANGLE_BEFORE, t, before)
        _style_points(rec, P.GRAVITY_ANGLE_BEFORE, ["before: raw gyro (deg)"], [BEFORE])


def _lcurve_xy(lc: LCurve) -> np.ndarray:
    """L-curve points in the 2D view: (log10 rho, -log10 eta), y negated to draw eta upwards."""
    return np.column_stack([_log10(lc.residual_norm), -_log10(lc.solution_norm)])


def _thin_labels(xy: np.ndarray, labels: list[str], keep: int, min_dist: float) -> list[str]:
    """Blank the labels of points closer than ``min_dist`` to a labelled one (small lambdas
    pile up at one end of the curve), always keeping the label at index ``keep``."""
    out = [""] * len(labels)
    shown: list[np.ndarray] = [xy[keep]] if 0 <= keep < len(xy) else []
    for i in range(len(xy) - 1, -1, -1):  # from the large-lambda end, where points spread
        if i == keep:
            continue
        if all(np.hypot(*(xy[i] - p)) >= min_dist for p in shown):
            out[i] = labels[i]
            shown.append(xy[i])
    return out


def _log_one_lcurve(rec: rr.RecordingStream, base: str, lc: LCurve, color: int,
                    name: str | None) -> np.ndarray:
    xy = _lcurve_xy(lc)
    ok = np.all(np.isfinite(xy), axis=1)
    lams = np.asarray(lc.lambdas, float)
    corner = lc.corner if 0 <= lc.corner < len(lams) and ok[lc.corner] else -1
    pts, lam_ok = xy[ok], lams[ok]
    keep = int(np.count_nonzero(ok[:corner])) if corner >= 0 else -1
    span = float(np.ptp(pts, axis=0).max()) if len(pts) else 0.0
    labels = _thin_labels(pts, [f"λ={la:.2g}" for la in lam_ok], keep, 0.06 * span)
    if keep >= 0:
        labels[keep] = ""  # the corner has its own, larger label
    rec.log(f"{base}/points",
            rr.Points2D(pts, labels=labels, colors=_rgba([color]),
                        radii=rr.Radius.ui_points(3.0), show_labels=True, draw_order=20.0),
            rr.AnyValues(**{"lambda": lam_ok}), static=True)
    rec.log(f"{base}/line", rr.LineStrips2D([pts], colors=_rgba([color]),
                                            labels=None if name is None else [name],
                                            radii=rr.Radius.ui_points(1.5), draw_order=10.0),
            static=True)
    if corner >= 0:
        c = corner
        prefix = "" if name is None else f"{name}: "
        rec.log(f"{base}/corner",
                rr.Points2D(xy[c:c + 1], labels=[f"{prefix}corner λ = {lams[c]:.3g}"],
                            colors=_rgba([CORNER]), radii=rr.Radius.ui_points(7.0),
                            show_labels=True, draw_order=30.0),
                rr.AnyValues(**{"lambda": float(lams[c]), "index": int(c),
                                "residual_norm": float(lc.residual_norm[c]),
                                "solution_norm": float(lc.solution_norm[c])}),
                static=True)
    return pts


def _ticks(lo: float, hi: float) -> np.ndarray:
    for step in (1.0, 0.5, 0.25, 0.1, 0.05):
        ticks = np.arange(np.ceil(lo / step) * step, hi + 1e-9, step)
        if len(ticks) >= 3:
            return ticks
    return np.array([lo, hi])


def _log_lcurve_frame(rec: rr.RecordingStream, xy: np.ndarray) -> None:
    """Axes with decade ticks: a Spatial2DView has none of its own."""
    x0, x1 = float(xy[:, 0].min()), float(xy[:, 0].max())
    y0, y1 = float(xy[:, 1].min()), float(xy[:, 1].max())
    span = max(x1 - x0, y1 - y0, 0.2)
    pad = 0.08 * span
    left, right, top, bottom = x0 - pad, x1 + pad, y0 - pad, y1 + pad
    xt = _ticks(left, right)
    yt = _ticks(-bottom, -top)  # log10 eta values
    strips = [[[left, bottom], [right, bottom]], [[left, bottom], [left, top]]]
    tick = 0.015 * span
    strips += [[[x, bottom], [x, bottom + tick]] for x in xt]
    strips += [[[left, -y], [left - tick, -y]] for y in yt]
    grey = 0x808080FF
    rec.log(f"{P.LCURVE_FRAME}/axes", rr.LineStrips2D(strips, colors=_rgba([grey]),
                                                      radii=rr.Radius.ui_points(1.0),
                                                      draw_order=1.0), static=True)
    pos = [[x, bottom + 3 * tick] for x in xt] + [[left - 3 * tick, -y] for y in yt]
    lab = [f"{10**x:.2g}" for x in xt] + [f"{10**y:.2g}" for y in yt]
    pos += [[(left + right) / 2, bottom + 7 * tick], [left, top - 3 * tick]]
    lab += ["residual norm ρ = |r_data|  (log scale) →",
            "↑ solution norm η = |θ − θ0|  (log scale)"]
    rec.log(f"{P.LCURVE_FRAME}/labels", rr.Points2D(pos, labels=lab, colors=_rgba([grey]),
                                                    radii=rr.Radius.ui_points(0.5),
                                                    show_labels=True, draw_order=2.0),
            static=True)


def _log_lcurves(result: Result, rec: rr.RecordingStream, rows: dict[str, int]) -> None:
    whole = result.whole
    lc = whole.lcurve
    if lc is None:
        return
    several = len(result.segments) > 1
    pts = [_log_one_lcurve(rec, P.LCURVE, lc, CALIBRATED, "whole session" if several else None)]
    if several:
        for seg in result.segments:
            if seg.acc.lcurve is not None:
                color = SEGMENT_COLORS[(seg.index + 1) % len(SEGMENT_COLORS)]
                pts.append(_log_one_lcurve(rec, P.lcurve_segment(seg.index), seg.acc.lcurve,
                                           color, f"segment {seg.index}"))
    allpts = np.vstack(pts)
    if len(allpts):
        _log_lcurve_frame(rec, allpts)

    # The sweep on the `lambda` timeline: what each lambda would have given.
    idx = np.arange(len(lc.lambdas))
    errs = np.array([block_norm_errors_mg(whole, result.detection.means, th) for th in lc.thetas])
    rms = np.sqrt(np.mean(errs**2, axis=1))
    params = np.array([acc_theta(whole.model_for(th)) for th in lc.thetas])
    series = {
        P.LAMBDA_LOG10: (np.log10(lc.lambdas), ["log10 λ"], [PREVIOUS]),
        P.LAMBDA_STATIC_RMS: (rms, ["static norm error RMS (mg)"], [CALIBRATED]),
        P.LAMBDA_STATIC_MAX: (np.max(np.abs(errs), axis=1), ["static norm error max |.| (mg)"],
                              [RAW]),
        P.LAMBDA_RESIDUAL: (_log10(lc.residual_norm), ["log10 ρ (residual norm)"], [RAW]),
        P.LAMBDA_SOLUTION: (_log10(lc.solution_norm), ["log10 η (solution norm)"], [MEASURED]),
        P.LAMBDA_MISALIGNMENT: (params[:, 0:3], [f"{n} (rad)" for n in ACC_PARAM_NAMES[0:3]],
                                XYZ),
        P.LAMBDA_SCALE: (params[:, 3:6], list(ACC_PARAM_NAMES[3:6]), XYZ),
        P.LAMBDA_BIAS: (params[:, 6:9], [f"{n} ({result.session.acc_unit})"
                                         for n in ACC_PARAM_NAMES[6:9]], XYZ),
    }
    for path, (v, names, colors) in series.items():
        rows[path] = _send_scalars(rec, path, idx, v, timeline=P.LAMBDA)
        _style_lines(rec, path, names, colors)
    if 0 <= lc.corner < len(idx):
        rows[P.LAMBDA_CHOSEN] = _send_scalars(rec, P.LAMBDA_CHOSEN, idx[lc.corner:lc.corner + 1],
                                              rms[lc.corner:lc.corner + 1], timeline=P.LAMBDA)
        _style_points(rec, P.LAMBDA_CHOSEN, [f"chosen λ = {lc.lambdas[lc.corner]:.3g}"],
                      [CORNER], size=8.0, marker="diamond")


def _log_iterations(result: Result, rec: rr.RecordingStream, rows: dict[str, int]) -> None:
    def acc(fit: AccFit, name: str) -> None:
        rep = fit.report
        if len(rep.trace_cost) == 0:
            return
        params = np.array([acc_theta(fit.model_for(th)) for th in rep.trace_theta])
        _log_trace(rec, rows, name, "accelerometer", rep.trace_cost, params[:, 0:3],
                   params[:, 3:6], params[:, 6:9], ACC_PARAM_NAMES)

    def gyro(fit: GyroFit, name: str) -> None:
        rep = fit.report
        if len(rep.trace_cost) == 0:
            return
        models = [fit.model_for(th) for th in rep.trace_theta]
        params = np.array([gyro_theta(m) for m in models])
        bias = np.array([m.b for m in models])
        _log_trace(rec, rows, name, "gyroscope", rep.trace_cost, params[:, 0:6], params[:, 6:9],
                   bias, GYRO_PARAM_NAMES + ("b_x", "b_y", "b_z"))

    if len(result.segments) > 1 or result.segments[0].acc is not result.whole:
        acc(result.whole, "whole")
    for seg in result.segments:
        acc(seg.acc, f"segment_{seg.index}")
        if seg.gyro is not None:
            gyro(seg.gyro, f"segment_{seg.index}")


def _log_trace(rec: rr.RecordingStream, rows: dict[str, int], fit: str, sensor: str,
               cost: np.ndarray, mis: np.ndarray, scale: np.ndarray, bias: np.ndarray,
               names: tuple[str, ...]) -> None:
    idx = np.arange(len(cost))
    n_mis = mis.shape[1]
    for what, v, nm in (("log10_cost", _log10(cost), ["log10 cost"]),
                        ("misalignment", mis, list(names[:n_mis])),
                        ("scale", scale, list(names[n_mis:n_mis + 3])),
                        ("bias", bias, ["b_x", "b_y", "b_z"])):
        path = P.iteration(fit, sensor, what)
        rows[path] = _send_scalars(rec, path, idx, v, timeline=P.ITERATION)
        colors = (XYZ if len(nm) == 3 else
                  [CALIBRATED] if len(nm) == 1 else SEGMENT_COLORS[: len(nm)])
        _style_lines(rec, path, nm, colors)
        _style_points(rec, path, nm, colors, size=3.0)


# --- results: plain values and the summary -------------------------------------------------------


def _log_results(result: Result, rec: rr.RecordingStream) -> None:
    s, q = result.session, result.quality
    for seg in result.segments:
        a = seg.acc
        rec.log(P.calibration(seg.index, "accelerometer"), rr.AnyValues(
            T=a.model.T.ravel(), K=a.model.K, b=a.model.b, params=acc_theta(a.model), std=a.std,
            param_names=list(ACC_PARAM_NAMES), **{"lambda": float(a.lam)},
            t_start=float(seg.t_start), t_end=float(seg.t_end), start=a.report.start_name,
            cost_start=float(a.report.cost_start), cost_end=float(a.report.cost),
            n_points=int(a.n_points), n_blocks=int(a.n_blocks),
            orientations=int(seg.orientations)), static=True)
        g = seg.gyro
        if g is not None:
            names = list(GYRO_PARAM_NAMES) + (["b_x", "b_y", "b_z"] if len(g.std) > 9 else [])
            rec.log(P.calibration(seg.index, "gyroscope"), rr.AnyValues(
                T=g.model.T.ravel(), K=g.model.K, b=g.model.b, params=gyro_theta(g.model),
                std=g.std, param_names=names, **{"lambda": float(g.lam)},
                bias_source=g.bias_source, nominal_scale=float(g.nominal_scale),
                transitions=int(len(g.u_meas)),
                transitions_excluded=int(g.excluded.sum()),
                cost_start=float(g.report.cost_start),
                cost_end=float(g.report.cost)), static=True)
    ga = q.gravity_angle_rms_deg or (None, None)
    rec.log(P.QUALITY, rr.AnyValues(
        static_norm_rms_mg_before=_nan(q.static_norm_rms_mg[0]),
        static_norm_rms_mg_after=_nan(q.static_norm_rms_mg[1]),
        sample_norm_rms_mg_before=_nan(q.sample_norm_rms_mg[0]),
        sample_norm_rms_mg_after=_nan(q.sample_norm_rms_mg[1]),
        gravity_angle_rms_deg_before=_nan(ga[0]), gravity_angle_rms_deg_after=_nan(ga[1]),
        block_norm_error_mg=np.asarray(q.block_norm_error_mg, float)), static=True)
    rec.log(P.INFO, rr.AnyValues(
        source=s.source, sha256=s.sha256 or "-", acc_unit_raw=s.acc_unit,
        acc_unit=result.calibration.acc_unit, g=float(result.calibration.g),
        gyro_unit_raw=s.gyro_unit if s.has_gyro else "-", **{"lambda": float(result.whole.lam)},
        n_blocks=int(len(result.block_times)), n_segments=int(len(result.segments)),
        grouping=result.grouping.mode, settings=json.dumps(result.settings.to_dict()),
        n_warnings=int(len(result.warnings)),
        warnings=np.array(result.warnings or [""], dtype=str)), static=True)
    rec.log(P.SUMMARY, rr.TextDocument(summary_markdown(result),
                                       media_type=rr.MediaType.MARKDOWN), static=True)


def _fmt(x: float | None, spec: str = ".6g") -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    return format(float(x), spec)


def summary_markdown(result: Result) -> str:
    """The calibration as a person reads it: quality first, then each segment's parameters."""
    s, q = result.session, result.quality
    unit, raw = result.calibration.acc_unit, s.acc_unit
    lines = [f"# IMU calibration: {Path(s.source).name}", ""]
    rate = f"{s.acc_rate:.4g} Hz"
    gyro = (f"gyroscope {len(s.gyro)} samples at {s.gyro_rate:.4g} Hz ({s.gyro_unit})"
            if s.has_gyro else "no gyroscope")
    lines += [f"- **Session:** {s.duration:.1f} s; accelerometer {len(s.acc)} samples at {rate} "
              f"({raw}); {gyro}"]
    lines += [f"- **Static blocks:** {len(result.block_times)}; **segments:** "
              f"{len(result.segments)} ({result.grouping.mode})"]
    lc = result.whole.lcurve
    how = (f"L-curve corner, point {lc.corner + 1} of {len(lc.lambdas)}" if lc is not None
           else "fixed")
    lines += [f"- **λ (accelerometer):** {result.whole.lam:.4g} ({how})", ""]

    lines += ["## Quality", "", "| figure | before | after |", "|---|---:|---:|"]
    b, a = q.static_norm_rms_mg
    lines.append(f"| static norm error, block means (RMS, mg) | {_fmt(b, '.4g')} | "
                 f"{_fmt(a, '.4g')} |")
    b, a = q.sample_norm_rms_mg
    lines.append("| static norm error, single samples (RMS, mg; mostly sensor noise) | "
                 f"{_fmt(b, '.4g')} | {_fmt(a, '.4g')} |")
    if q.gravity_angle_rms_deg is not None:
        b, a = q.gravity_angle_rms_deg
        lines.append(f"| gravity prediction error (RMS, deg) | {_fmt(b, '.4g')} | "
                     f"{_fmt(a, '.4g')} |")
    lines += [f"- {n}" for n in q.notes]
    lines.append("")

    for seg in result.segments:
        a = seg.acc
        lines += [f"## Segment {seg.index}: {seg.t_start:.2f}–{seg.t_end:.2f} s, "
                  f"{seg.blocks[1] - seg.blocks[0]} blocks, {seg.orientations} orientations", ""]
        lines += [f"### Accelerometer: a = T K (a_raw − b), a in {unit}", "",
                  "| parameter | value | std. error |", "|---|---:|---:|"]
        params = acc_theta(a.model)
        units = ["rad"] * 3 + [f"{unit}/{raw}"] * 3 + [raw] * 3
        for n, v, e, u in zip(ACC_PARAM_NAMES, params, a.std, units):
            lines.append(f"| {n} ({u}) | {_fmt(v)} | {_fmt(e, '.2g')} |")
        starts = ", ".join(f"{k} {v:.3g}" for k, v in a.starts.items())
        lines += ["", f"λ = {a.lam:.4g}; LM from the *{a.report.start_name}* start (costs reached: "
                  f"{starts}); cost {a.report.cost_start:.3g} → {a.report.cost:.3g}; "
                  f"{a.n_points} points from {a.n_blocks} blocks", ""]
        g = seg.gyro
        if g is None:
            continue
        graw = s.gyro_unit
        lines += ["### Gyroscope: w = T_g K_g (w_raw − b_g), w in rad/s", "",
                  "| parameter | value | std. error |", "|---|---:|---:|"]
        params = gyro_theta(g.model)
        units = ["rad"] * 6 + [f"rad/s per {graw}" if graw != "rad/s" else ""] * 3
        for n, v, e, u in zip(GYRO_PARAM_NAMES, params, g.std, units):
            label = f"{n} ({u})" if u else n
            lines.append(f"| {label} | {_fmt(v)} | {_fmt(e, '.2g')} |")
        bstd = g.std[9:12] if len(g.std) > 9 else [None] * 3
        for n, v, e in zip(("b_x", "b_y", "b_z"), g.model.b, bstd):
            lines.append(f"| {n} ({graw}) | {_fmt(v)} | {_fmt(e, '.2g')} |")
        lines += ["", f"bias: {g.bias_source}; λ = {g.lam:.3g}; {len(g.u_meas)} rotations; "
                  f"cost {g.report.cost_start:.3g} → {g.report.cost:.3g}", ""]

    lines += ["## Warnings", ""]
    lines += [f"- {w}" for w in result.warnings] or ["none"]
    lines.append("")
    return "\n".join(lines)


# --- files ---------------------------------------------------------------------------------------


def new_recording() -> rr.RecordingStream:
    """A fresh recording stream (its own id: two runs in one process never merge)."""
    return rr.RecordingStream(P.APPLICATION_ID, recording_id=uuid.uuid4())


def save_recording(result: Result, path: str | os.PathLike | BinaryIO) -> dict[str, int]:
    """Write ``result`` with its layout as one ``.rrd``: to ``path`` atomically (a temporary
    file in the same directory, then a rename), or to an open binary file (a run's
    transaction owns the rename). Bounded and interruptible: see :mod:`viewer.rrd_file`.

    Returns the rows logged per temporal entity (see :func:`log_result`).
    """
    if not hasattr(path, "write"):
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            return save_recording(result, f)
    from .blueprint import blueprint
    from .rrd_file import rrd_sink

    rec = new_recording()
    with rrd_sink(rec, path, default_blueprint=blueprint(result)):
        rec.send_recording_name(Path(result.session.source).name or "imucal")
        rows = log_result(result, rec)
    return rows
