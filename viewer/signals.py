"""The time-line entities of the Overview and Signals tabs: magnitudes, axes, the detector and
its lanes, and the static blocks' norm errors."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import rerun as rr

from . import paths as P
from .columns import (
    AFTER,
    BEFORE,
    BETWEEN,
    CALIBRATED,
    RAW,
    SEGMENT_COLORS,
    STILL,
    XYZ,
    log10_axis,
    rgba,
    send_scalars,
    style_lines,
    style_points,
)
from .signal_rows import Series, SignalRows

if TYPE_CHECKING:
    from imucal.result import Result


def log_signals(result: Result, rec: rr.RecordingStream, rows: dict[str, int],
                signals: SignalRows) -> None:
    """The magnitudes and per-axis signals, as many rows as a screen shows plus the
    accelerometer's still samples at full rate (:mod:`viewer.decimate` says why), as
    :func:`~viewer.signal_rows.signal_rows` made them."""
    s = result.session
    unit = result.calibration.acc_unit
    acc = signals.acc
    rows[P.ACC_MAGNITUDE] = _send(rec, P.ACC_MAGNITUDE, acc.magnitude)
    style_lines(rec, P.ACC_MAGNITUDE, [f"raw |a| ({unit}, nominal)", f"calibrated |a| ({unit})"],
                [RAW, CALIBRATED])
    for path, series, label in ((P.ACC_RAW, acc.raw, s.acc_unit),
                                (P.ACC_CALIBRATED, acc.calibrated, unit)):
        rows[path] = _send(rec, path, series)
        style_lines(rec, path, [f"{c} ({label})" for c in "xyz"], XYZ)

    gyro = signals.gyro
    if gyro is None:
        return
    rows[P.GYRO_MAGNITUDE] = _send(rec, P.GYRO_MAGNITUDE, gyro.magnitude)
    style_lines(rec, P.GYRO_MAGNITUDE, ["raw |w| (rad/s, nominal)", "calibrated |w| (rad/s)"],
                [RAW, CALIBRATED])
    for path, series, label in ((P.GYRO_RAW, gyro.raw, s.gyro_unit),
                                (P.GYRO_CALIBRATED, gyro.calibrated, "rad/s")):
        rows[path] = _send(rec, path, series)
        style_lines(rec, path, [f"{c} ({label})" for c in "xyz"], XYZ)


def _send(rec: rr.RecordingStream, path: str, series: Series) -> int:
    """The rows, and beside them (static AnyValues) how they were decimated: the choice is
    the data's (its length and its still blocks), so the recording says what it was."""
    d = series.decimation
    rec.log(path, rr.AnyValues(samples=d.samples, rows=d.rows, still_bucket=d.still_bucket,
                               moving_bucket=d.moving_bucket), static=True)
    return send_scalars(rec, path, series.t, series.v)


def log_detector(result: Result, rec: rr.RecordingStream, rows: dict[str, int],
                 signals: SignalRows) -> None:
    det, t = result.detection, result.session.t_acc
    rows[P.DETECTOR_STATISTIC] = _send(rec, P.DETECTOR_STATISTIC, signals.detector)
    style_lines(rec, P.DETECTOR_STATISTIC, ["log10 s2 (M1)"], [0x4E79A7FF])
    rows[P.DETECTOR_THRESHOLD] = send_scalars(rec, P.DETECTOR_THRESHOLD, [t[0], t[-1]],
                                              np.full(2, log10_axis(det.threshold)))
    style_lines(rec, P.DETECTOR_THRESHOLD, [f"log10 threshold (k = {result.detection.k:.3g})"],
                [BEFORE], width=2.0)
    _log_lanes(result, rec, rows)


def _log_lanes(result: Result, rec: rr.RecordingStream, rows: dict[str, int]) -> None:
    """Still blocks and segments as state lanes: a state at each start, reset at each end."""
    times = result.block_times.ravel()  # t_start, t_end of block 0, then block 1, ...
    states = ["still", ""] * len(result.block_times)
    # No text in the bars: a still block is a few pixels wide at the default window, where
    # "still" was cut to "sti"; the lanes' title names the green.
    rec.log(P.DETECTOR_BLOCKS, rr.StateConfiguration(values=["still"], labels=[" "],
                                                     colors=rgba([STILL])), static=True)
    rec.send_columns(P.DETECTOR_BLOCKS, indexes=[rr.TimeColumn(P.TIME, duration=times)],
                     columns=rr.StateChange.columns(state=states))
    rows[P.DETECTOR_BLOCKS] = len(times)

    seg_t, seg_s = [], []
    names = [f"segment {seg.number}" for seg in result.segments]
    for seg, name in zip(result.segments, names):
        seg_t.append(seg.t_start)
        seg_s.append(name)
        if seg is not result.segments[-1]:
            seg_t.append(seg.t_end)
            seg_s.append("between segments")
    seg_t.append(result.segments[-1].t_end)
    seg_s.append("")
    colors = [SEGMENT_COLORS[i % len(SEGMENT_COLORS)] for i in range(len(names))]
    rec.log(P.DETECTOR_SEGMENTS, rr.StateConfiguration(
        values=[*names, "between segments"],
        labels=[*names, "between segments (mean of neighbours)"],
        colors=rgba([*colors, BETWEEN])), static=True)
    rec.send_columns(P.DETECTOR_SEGMENTS, indexes=[rr.TimeColumn(P.TIME, duration=seg_t)],
                     columns=rr.StateChange.columns(state=seg_s))
    rows[P.DETECTOR_SEGMENTS] = len(seg_t)


def log_block_errors(result: Result, rec: rr.RecordingStream, rows: dict[str, int]) -> None:
    q = result.quality
    mid = result.block_middles
    if q.block_norm_error_before_mg is not None:
        rows[P.BLOCK_ERROR_BEFORE] = send_scalars(rec, P.BLOCK_ERROR_BEFORE, mid,
                                                  q.block_norm_error_before_mg)
        style_points(rec, P.BLOCK_ERROR_BEFORE, ["before (mg)"], [BEFORE])
    rows[P.BLOCK_ERROR_AFTER] = send_scalars(rec, P.BLOCK_ERROR_AFTER, mid,
                                             q.block_norm_error_mg)
    style_points(rec, P.BLOCK_ERROR_AFTER, ["after (mg)"], [AFTER])
