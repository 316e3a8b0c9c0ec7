"""The Optimiser tab's entities: cost and raw-unit parameters at each accepted step of every
fit, on the ``iteration`` timeline (``AccFit.trace_params``, ``GyroFit.trace_params`` and
``trace_bias``, from what the optimiser's report records)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import rerun as rr

from imucal.models import ACC_PARAM_NAMES, GYRO_PARAM_NAMES

from . import paths as P
from .columns import (
    CALIBRATED,
    SEGMENT_COLORS,
    XYZ,
    log10_axis,
    send_scalars,
    style_lines,
    style_points,
)

if TYPE_CHECKING:
    from imucal.result import Result
    from imucal.stages.accel import AccFit
    from imucal.stages.gyro import GyroFit


def log_iterations(result: Result, rec: rr.RecordingStream, rows: dict[str, int]) -> None:
    if len(result.segments) > 1 or result.segments[0].acc is not result.whole:
        _log_acc(rec, rows, result.whole, "whole")
    for seg in result.segments:
        _log_acc(rec, rows, seg.acc, f"segment_{seg.index}")
        if seg.gyro is not None:
            _log_gyro(rec, rows, seg.gyro, f"segment_{seg.index}")


def _log_acc(rec: rr.RecordingStream, rows: dict[str, int], fit: AccFit, name: str) -> None:
    if len(fit.report.trace_cost) == 0:
        return
    p = fit.trace_params
    _log_trace(rec, rows, name, "accelerometer", fit.report.trace_cost,
               {"misalignment": (p[:, 0:3], ACC_PARAM_NAMES[0:3]),
                "scale": (p[:, 3:6], ACC_PARAM_NAMES[3:6]),
                "bias": (p[:, 6:9], ACC_PARAM_NAMES[6:9])})


def _log_gyro(rec: rr.RecordingStream, rows: dict[str, int], fit: GyroFit, name: str) -> None:
    if len(fit.report.trace_cost) == 0:
        return
    p = fit.trace_params
    _log_trace(rec, rows, name, "gyroscope", fit.report.trace_cost,
               {"misalignment": (p[:, 0:6], GYRO_PARAM_NAMES[0:6]),
                "scale": (p[:, 6:9], GYRO_PARAM_NAMES[6:9]),
                "bias": (fit.trace_bias, ("b_x", "b_y", "b_z"))})


def _log_trace(rec: rr.RecordingStream, rows: dict[str, int], fit: str, sensor: str,
               cost: np.ndarray, params: dict[str, tuple[np.ndarray, tuple[str, ...]]]) -> None:
    idx = np.arange(len(cost))
    series = {"log10_cost": (log10_axis(cost), ("log10 cost",)), **params}
    for what, (v, names) in series.items():
        path = P.iteration(fit, sensor, what)
        rows[path] = send_scalars(rec, path, idx, v, timeline=P.ITERATION)
        colors = (XYZ if len(names) == 3 else
                  [CALIBRATED] if len(names) == 1 else SEGMENT_COLORS[: len(names)])
        style_lines(rec, path, list(names), colors)
        style_points(rec, path, list(names), colors, size=3.0)
