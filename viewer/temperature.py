"""The Temperature tab's entities (issue 24, item 4; method.md §12): each sensor's bias as a
polynomial in temperature (M16, M17; ``Result.temperature``), drawn against temperature as 2D
plots (:mod:`viewer.plot2d`), with the span of temperatures seen marked (the model is held
constant outside it, never extrapolated) and the still blocks on heating and cooling legs
apart (``BiasPolynomial.legs``: red heating, blue cooling, grey neither).

- the accelerometer: ``b(T) - b_0`` per axis (``bias_at``; mg for a triad in g), and each still
  block's ``|a|/g - 1`` (mg) with the constant-bias fit (``before_mg``: what the polynomial
  explains) and after it (``residuals``); a still block sees the accelerometer's bias only
  along gravity, so there is no per-axis data point to draw;
- the scales' change (ppm, ``scale_at``) where the data determined one (``scale_slope``);
- the gyroscope: per axis, each block's bias (``points()``, the data M16 was fitted to) and
  the fitted polynomial, less ``b_0`` (deg/s for a gyroscope in rad/s);
- the temperature over the session with each block's temperature on its leg (time series).

Every other triad with its own fit (``Result.triads``, each on its IMU's temperature) is drawn
beside the reference's: its accelerometer's ``b(T) - b_0`` as dotted curves in the axes'
colours (``t2_bias_x``…), its gyroscope's points and fit in the triad's colour on each axis's
plot (``t2_points``, ``t2_fit``), and its orders and coefficients in the note.

Each series holds AnyValues ``degC`` and the values as logged. Nothing is logged without a
bias in temperature.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from imucal.stages.temperature import block_legs, block_temperatures

from . import paths as P
from .columns import (
    AFTER,
    BEFORE,
    GREY,
    MEASURED,
    SEGMENT_COLORS,
    XYZ,
    send_scalars,
    style_lines,
    style_points,
)
from .decimate import SCREEN_ROWS, envelope
from .layout import Box
from .plot2d import Axis, Mark, Series, linear_axis, log_plot

if TYPE_CHECKING:
    from imucal.result import Result
    from imucal.stages.temperature import BiasPolynomial
    from imucal.streams import Stream

AXES = "xyz"
LEGS = (("heating", 1, BEFORE), ("cooling", -1, AFTER), ("steady", 0, GREY))
SPAN = 0xBAB0ACFF
CURVE_POINTS = 121
TAB_W, TAB_H = 1600.0, 872.0  # the tab's size at the default window, pixels


def fit_of(result: Result | None, sensor: str) -> BiasPolynomial | None:
    if result is None:
        return None
    return next((f for f in result.temperature if f.sensor == sensor), None)


def other_fits(result: Result | None, sensor: str) -> list[tuple[int, str, str | None,
                                                                 BiasPolynomial]]:
    """Each other triad's fit of ``sensor`` (number from 2 as in the Triads tab, its name,
    its raw unit, the fit), in the triads' order."""
    out = []
    for i, tri in enumerate(() if result is None else result.triads, start=2):
        fit = fit_of(tri.result, sensor)
        if fit is not None:
            s = tri.result.session
            unit = s.acc_unit if sensor == "accelerometer" else s.gyro_unit
            name = tri.name if sensor == "accelerometer" else (tri.gyro or tri.name)
            out.append((i, name, unit, fit))
    return out


def triad_color(i: int) -> int:
    """Triad ``i``'s colour (2: the second), apart from the reference's."""
    return SEGMENT_COLORS[(i - 1) % len(SEGMENT_COLORS)]


def plots(result: Result | None) -> tuple[list[str], list[str]]:
    """The 2D plots of each column (accelerometer, gyroscope): their paths."""
    acc = fit_of(result, "accelerometer")
    gyro = fit_of(result, "gyroscope")
    left = [] if acc is None else [P.temp_plot("accelerometer", "bias"),
                                   P.temp_plot("accelerometer", "norm")]
    if acc is not None and acc.scale_slope is not None:
        left.append(P.temp_plot("accelerometer", "scale"))
    right = [] if gyro is None else [P.temp_plot("gyroscope", f"bias_{a}") for a in AXES]
    return left, right


def column_shares(result: Result | None) -> list[float]:
    left, right = plots(result)
    return [s for s, c in ((1.0, left), (1.0, right)) if c] + [0.8]


def boxes(result: Result | None) -> dict[str, Box]:
    """Each plot's box: its column's width over the plots stacked in it (the layout and the
    drawing share it)."""
    shares = column_shares(result)
    width = TAB_W * shares[0] / sum(shares) - 6
    out = {}
    for col in plots(result):
        for path in col:
            out[path] = Box.fitting(width, TAB_H / len(col) - 30, left=60, right=92)
    return out


def display(unit: str | None, sensor: str) -> tuple[str, float]:
    """The unit a bias is drawn in and the factor from the raw unit to it."""
    if sensor == "gyroscope":
        return ("deg/s", float(np.degrees(1.0))) if unit == "rad/s" else (unit or "raw", 1.0)
    return ("mg", 1e3) if unit == "g" else (unit or "raw", 1.0)


def temp_stream(result: Result) -> Stream | None:
    """The session's temperature stream (the calibrated accelerometer's instance's where there
    are several, else the first), as the run chose it (imucal.pipeline)."""
    temps = [s for s in result.session.others if s.kind == "temp" and s.samples >= 2]
    if not temps:
        return None
    named = result.session.chosen[0].split(" ")[1] if result.session.chosen else None
    return next((s for s in temps if s.instance == named), temps[0])


def _grid(fit: BiasPolynomial) -> np.ndarray:
    lo, hi = fit.span
    pad = max(0.15 * (hi - lo), 2.0)  # a little either side: the model held flat there
    return np.linspace(lo - pad, hi + pad, CURVE_POINTS)


def _axis_x(fit: BiasPolynomial) -> Axis:
    g = _grid(fit)
    xa = linear_axis(g, pad=0.0)
    return Axis(float(g[0]), float(g[-1]), xa.ticks, [f"{t} °C" for t in xa.labels])


def _axis_y(values: list[np.ndarray]) -> Axis:
    return linear_axis(np.concatenate([np.ravel(v) for v in values]), pad=0.08)  # unit: title


def _marks(fit: BiasPolynomial) -> list[Mark]:
    lo, hi = fit.span
    return [Mark(lo, f"{lo:.1f} °C", SPAN), Mark(hi, f"{hi:.1f} °C (span seen)", SPAN)]


def _legs(fit: BiasPolynomial) -> np.ndarray:
    n = 0 if fit.temps is None else len(fit.temps)
    return np.zeros(n, int) if fit.legs is None else np.asarray(fit.legs, int)


def _leg_series(fit: BiasPolynomial, y: np.ndarray, prefix: str, unit: str) -> list[Series]:
    out = []
    legs = _legs(fit)
    for name, leg, color in LEGS:
        on = legs == leg
        if on.any():
            out.append(Series(f"{prefix}{name}", name, color, fit.temps[on], y[on], line=False,
                              size=3.0, values={"degC": fit.temps[on], unit: y[on],
                                                "block": np.asarray(fit.used)[on]}))
    return out


def log_temperature(result: Result, rec: rr.RecordingStream, rows: dict[str, int]) -> None:
    if not result.temperature:
        return
    box = boxes(result)
    acc = fit_of(result, "accelerometer")
    if acc is not None:
        _log_accelerometer(acc, result.session.acc_unit, box, rec,
                           other_fits(result, "accelerometer"))
    gyro = fit_of(result, "gyroscope")
    if gyro is not None:
        _log_gyroscope(gyro, result.session.gyro_unit, box, rec, other_fits(result, "gyroscope"))
    _log_time(result, rec, rows)
    rec.log(P.TEMP_NOTE, rr.TextDocument(temperature_note(result), media_type="text/markdown"),
            static=True)


def _log_accelerometer(fit: BiasPolynomial, unit: str | None, box: dict[str, Box],
                       rec: rr.RecordingStream, others: list | None = None) -> None:
    shown, k = display(unit, "accelerometer")
    grid = _grid(fit)
    xa = _axis_x(fit)
    db = (fit.bias_at(grid) - fit.b0) * k
    path = P.temp_plot("accelerometer", "bias")
    series = [Series(f"bias_{a}", f"b{a}(T) − b0{a}", XYZ[i], grid, db[:, i], size=0.6,
                     values={"degC": grid, shown: db[:, i]}) for i, a in enumerate(AXES)]
    ys = [db]
    for n, name, o_unit, o in others or ():  # each other triad's, dotted, on the same grid
        o_shown, o_k = display(o_unit, "accelerometer")
        ob = (o.bias_at(grid) - o.b0) * o_k
        ys.append(ob)
        series += [Series(f"t{n}_bias_{a}", f"{name}: b{a}(T) − b0{a}", XYZ[i], grid, ob[:, i],
                          line=False, size=1.2, values={"degC": grid, o_shown: ob[:, i]})
                   for i, a in enumerate(AXES)]
    log_plot(rec, path, box[path], xa, _axis_y(ys), series, _marks(fit))
    if fit.before_mg is not None and fit.temps is not None:
        path = P.temp_plot("accelerometer", "norm")
        series = _leg_series(fit, np.asarray(fit.before_mg), "constant_", "mg")
        after = np.asarray(fit.residuals, float)
        series.append(Series("with_polynomial", "with b(T)", MEASURED, fit.temps, after,
                             line=False, size=2.0, values={"degC": fit.temps, "mg": after}))
        log_plot(rec, path, box[path], xa, _axis_y([fit.before_mg, after]), series,
                 _marks(fit))
    if fit.scale_slope is not None and fit.model is not None:
        path = P.temp_plot("accelerometer", "scale")
        ppm = (fit.scale_at(grid) / fit.model.K[None, :] - 1.0) * 1e6
        series = [Series(f"scale_{a}", f"K{a}(T)/K{a} − 1", XYZ[i], grid, ppm[:, i], size=0.6,
                         values={"degC": grid, "ppm": ppm[:, i]}) for i, a in enumerate(AXES)]
        log_plot(rec, path, box[path], xa, _axis_y([ppm]), series, _marks(fit))


def _log_gyroscope(fit: BiasPolynomial, unit: str | None, box: dict[str, Box],
                   rec: rr.RecordingStream, others: list | None = None) -> None:
    shown, k = display(unit, "gyroscope")
    grid = _grid(fit)
    xa = _axis_x(fit)
    curve = (fit.bias_at(grid) - fit.b0) * k
    pts = fit.points()
    data = None if pts is None else (pts - fit.b0) * k
    for i, a in enumerate(AXES):
        path = P.temp_plot("gyroscope", f"bias_{a}")
        series = [] if data is None else _leg_series(fit, data[:, i], "", shown)
        series.append(Series("fit", f"order {fit.order}", XYZ[i], grid, curve[:, i], size=0.6,
                             values={"degC": grid, shown: curve[:, i]}))
        ys = [curve[:, i]] + ([] if data is None else [data[:, i]])
        for n, name, o_unit, o in others or ():  # each other triad's, in its colour
            o_shown, o_k = display(o_unit, "gyroscope")
            oc = (o.bias_at(grid) - o.b0)[:, i] * o_k
            ys.append(oc)
            pts = o.points()
            if pts is not None:
                op = (pts - o.b0)[:, i] * o_k
                ys.append(op)
                series.append(Series(f"t{n}_points", f"{name}: still blocks", triad_color(n),
                                     o.temps, op, line=False, size=2.0,
                                     values={"degC": o.temps, o_shown: op,
                                             "block": np.asarray(o.used)}))
            series.append(Series(f"t{n}_fit", f"{name}: order {o.order}", triad_color(n), grid,
                                 oc, size=0.6, values={"degC": grid, o_shown: oc}))
        log_plot(rec, path, box[path], xa, _axis_y(ys), series, _marks(fit))


def _log_time(result: Result, rec: rr.RecordingStream, rows: dict[str, int]) -> None:
    stream = temp_stream(result)
    if stream is None:
        return
    t = np.asarray(stream.t, float)
    v = np.asarray(stream.values, float).reshape(len(t), -1)[:, 0]
    tt, vv = envelope(t, v, SCREEN_ROWS)
    rows[P.TEMP_SERIES] = send_scalars(rec, P.TEMP_SERIES, tt, vv)
    style_lines(rec, P.TEMP_SERIES, [f"{stream.name} (°C)"], [GREY])
    bt = result.block_times
    temps = block_temperatures(t, v, bt)
    legs = block_legs(t, v, bt)
    mid = result.block_middles
    for name, leg, color in LEGS:
        on = (legs == leg) & np.isfinite(temps)
        if on.any():
            path = P.temp_blocks(name)
            rows[path] = send_scalars(rec, path, mid[on], temps[on])
            style_points(rec, path, [f"still block, {name}"], [color], size=3.5)


def temperature_note(result: Result) -> str:
    """The note (markdown): each fit's order, span, the held-out RMS per order, the
    coefficients, hysteresis and what the core said."""
    lines = ["**Temperature** (method.md §12): bias in temperature, held constant outside the "
             "span seen", ""]
    runs = [("", result)] + [(f"{tri.name}, ", tri.result) for tri in result.triads
                             if tri.result is not None and tri.result.temperature]
    for who, run in runs:
        lines += _fit_lines(who, run)
    notes = [(who, n) for who, run in runs for f in run.temperature for n in f.notes]
    return "\n".join(lines + ([""] + [f"- {who}{n}" for who, n in notes] if notes else []))


def _fit_lines(who: str, result: Result) -> list[str]:
    """One run's fits in the note (``who``: the triad's name before the sensor's, or "" for
    the reference's)."""
    lines = []
    for f in result.temperature:
        acc = f.sensor == "accelerometer"
        unit = result.session.acc_unit if acc else result.session.gyro_unit
        cv = ", ".join(f"{p}: {v:.3g}" for p, v in enumerate(f.cv_rms) if np.isfinite(v))
        cv_unit = f"{result.calibration.acc_unit}, of |a| − g" if acc else unit
        lines.append(f"- **{who}{f.sensor}**: order {f.order} over {f.span[0]:.1f}–"
                     f"{f.span[1]:.1f} °C ({f.blocks} still blocks, T0 {f.t0:.1f} °C); held-out "
                     f"RMS per order {cv or '–'} ({cv_unit})")
        for j, c in enumerate(f.coefs):
            lines.append(f"  - c{j}: " + ", ".join(f"{v:+.4g}" for v in c)
                         + f" {unit or 'raw'}/°C^{j}")
        if f.scale_slope is not None:
            lines.append("  - scales: " + ", ".join(f"{v * 1e6:+.0f}" for v in f.scale_slope)
                         + " ppm/°C")
    return lines


# --- the layout ---------------------------------------------------------------------------------


def temperature_tab(result: Result, time_axis, lanes) -> rrb.Horizontal:
    """Bias (and scale) against temperature, the accelerometer's column and the gyroscope's,
    then the temperature over the session over the still blocks' lane, and the note.
    ``time_axis`` and ``lanes`` are the layout's (:mod:`viewer.blueprint`)."""
    titles = plot_titles(result)
    box = boxes(result)
    cols = []
    for col in plots(result):
        if col:
            cols.append(rrb.Vertical(*[rrb.Spatial2DView(
                name=titles[p], origin=p, contents=[f"{p}/**"],
                visual_bounds=rrb.VisualBounds2D(x_range=box[p].bounds()[0],
                                                 y_range=box[p].bounds()[1])) for p in col]))
    when = rrb.TimeSeriesView(
        name="Temperature (°C); still blocks heating red, cooling blue",
        origin="/", contents=[P.TEMP_SERIES] + [P.temp_blocks(n) for n, _, _ in LEGS],
        axis_x=time_axis(), plot_legend=rrb.PlotLegend(visible=False))
    cols.append(rrb.Vertical(when, lanes(), rrb.TextDocumentView(name="Temperature",
                                                                 origin=P.TEMP_NOTE),
                             row_shares=[1.2, 0.45, 2.0]))
    return rrb.Horizontal(*cols, column_shares=column_shares(result), name="Temperature")


def plot_titles(result: Result) -> dict[str, str]:
    acc, gyro = fit_of(result, "accelerometer"), fit_of(result, "gyroscope")
    out = {}
    if acc is not None:
        u, _ = display(result.session.acc_unit, "accelerometer")
        out[P.temp_plot("accelerometer", "bias")] = (
            f"Accelerometer bias b(T) − b0 ({u}), order {acc.order}: x red, y green, z blue")
        out[P.temp_plot("accelerometer", "norm")] = (
            "Accelerometer |ā|/g − 1 per still block (mg): constant bias (heating red, cooling "
            "blue, steady grey), with b(T) green")
        out[P.temp_plot("accelerometer", "scale")] = "Accelerometer scale K(T)/K − 1 (ppm)"
    if gyro is not None:
        u, _ = display(result.session.gyro_unit, "gyroscope")
        for a in AXES:
            out[P.temp_plot("gyroscope", f"bias_{a}")] = (
                f"Gyroscope bias {a} − b0 ({u}) per still block and order {gyro.order} fit")
    return out
