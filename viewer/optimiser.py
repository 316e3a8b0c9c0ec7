"""The Optimiser tab's entities: per sensor, 2D plots (:mod:`viewer.plot2d`) of the cost and the
raw-unit parameters at each accepted step of every fit, against the step
(``AccFit.trace_params``, ``GyroFit.trace_params`` and ``trace_bias``, from what the
optimiser's report records)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import rerun as rr

from imucal.models import ACC_PARAM_NAMES, GYRO_PARAM_NAMES

from . import paths as P
from .columns import CALIBRATED, SEGMENT_COLORS, XYZ, log10_axis
from .layout import TRACE_BOX, TRACE_BOX_WIDE
from .plot2d import Series, linear_axis, log_axis, log_plot, step_axis

if TYPE_CHECKING:
    from imucal.result import Result

WHATS = ("log10_cost", "misalignment", "scale", "bias")


def fits(result: Result) -> list[tuple[str, object, object]]:
    """(name, accelerometer fit, gyroscope fit or None) of every fit the optimiser ran: the
    first whole-session fit when it is not segment 1's, then each segment's."""
    out = []
    if len(result.segments) > 1 or result.segments[0].acc is not result.whole:
        out.append(("whole", result.whole, None))
    out += [(f"segment_{s.number}", s.acc, s.gyro) for s in result.segments]
    return out


def log_iterations(result: Result, rec: rr.RecordingStream, rows: dict[str, int]) -> None:
    runs = fits(result)
    gyro = any(g is not None for _, _, g in runs)
    box = TRACE_BOX if gyro else TRACE_BOX_WIDE
    acc = {name: _acc_traces(a) for name, a, _ in runs if len(a.report.trace_cost)}
    _log_sensor(rec, "accelerometer", acc, box, result.session.acc_unit)
    if gyro:
        traces = {name: _gyro_traces(g) for name, _, g in runs
                  if g is not None and len(g.report.trace_cost)}
        _log_sensor(rec, "gyroscope", traces, box, result.session.gyro_unit)


def _acc_traces(fit) -> dict[str, tuple[np.ndarray, tuple[str, ...]]]:
    p = fit.trace_params
    return {"log10_cost": (np.asarray(fit.report.trace_cost, float)[:, None], ("cost",)),
            "misalignment": (p[:, 0:3], ACC_PARAM_NAMES[0:3]),
            "scale": (p[:, 3:6], ACC_PARAM_NAMES[3:6]),
            "bias": (p[:, 6:9], ACC_PARAM_NAMES[6:9])}


def _gyro_traces(fit) -> dict[str, tuple[np.ndarray, tuple[str, ...]]]:
    p = fit.trace_params
    return {"log10_cost": (np.asarray(fit.report.trace_cost, float)[:, None], ("cost",)),
            "misalignment": (p[:, 0:6], GYRO_PARAM_NAMES[0:6]),
            "scale": (p[:, 6:9], GYRO_PARAM_NAMES[6:9]),
            "bias": (fit.trace_bias, ("b_x", "b_y", "b_z"))}


def _log_sensor(rec: rr.RecordingStream, sensor: str, traces: dict, box, unit: str) -> None:
    """One plot per quantity; every fit's trace in it (named by fit when there are several)."""
    if not traces:
        return
    several = len(traces) > 1
    n = max(len(t["log10_cost"][0]) for t in traces.values())
    xa = step_axis(n)
    for what in WHATS:
        series, ys = [], []
        for k, (fit, t) in enumerate(traces.items()):
            v, names = t[what]
            y = log10_axis(v) if what == "log10_cost" else v
            ys.append(y)
            for i, name in enumerate(names):
                if len(names) == 1:
                    color = SEGMENT_COLORS[k % len(SEGMENT_COLORS)] if several else CALIBRATED
                else:
                    color = (XYZ if len(names) == 3 else SEGMENT_COLORS)[i]
                label = f"{fit.replace('segment_', 'seg ')} {name}" if several else name
                label += {"bias": f" ({unit})", "misalignment": " (rad)"}.get(what, "")
                values = {"step": np.arange(len(v))}
                if what == "log10_cost":
                    values["cost"] = v[:, 0]
                series.append(Series(f"{fit}/{name}", label, color,
                                     np.arange(len(v), dtype=float), y[:, i], values=values,
                                     size=3.0))
        yall = np.concatenate([y.ravel() for y in ys])
        # The cost on at least a decade: a fall of 0.06 % on an axis fitted to the points
        # looked like a cliff (issue 21); the title says by how much it fell.
        ya = log_axis(yall, min_span=1.0) if what == "log10_cost" else linear_axis(yall)
        log_plot(rec, P.iteration(sensor, what), box, xa, ya, series)


def cost_falls(result: Result, sensor: str) -> list[float]:
    """How much each fit of ``sensor`` (``accelerometer`` or ``gyroscope``) lowered its cost
    from the start to the end, in % of the start (the optimiser's own trace, ``FitReport
    .trace_cost``): for the Optimiser tab's titles."""
    out = []
    for _, acc, gyro in fits(result):
        fit = acc if sensor == "accelerometer" else gyro
        if fit is None or len(fit.report.trace_cost) == 0:
            continue
        c = np.asarray(fit.report.trace_cost, float)
        if c[0] > 0:
            out.append(float(100.0 * (c[0] - c[-1]) / c[0]))
    return out


def cost_title(result: Result | None, sensor: str) -> str:
    """``Accelerometer: cost (log scale) per accepted step, fell 0.0597 %``."""
    falls = [] if result is None else cost_falls(result, sensor)
    def fall(pct: float) -> str:  # 99.97 % reads "100 %": say how many times lower
        if pct < 99.0:
            return f"{pct:.3g} %"
        times = float(f"{100.0 / max(100.0 - pct, 1e-300):.3g}")  # 3 digits: 3,780-fold
        return f"{times:,.0f}-fold" if times >= 100 else f"{times:g}-fold"

    change = ""
    if len(falls) == 1:
        change = f", fell {fall(falls[0])}"
    elif falls:
        change = f", fell {fall(min(falls))} to {fall(max(falls))}"
    return f"{sensor.capitalize()}: cost (log scale, a decade at least) per accepted step{change}"
