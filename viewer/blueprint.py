"""The layout stored in every recording: tabs that need no arranging.

=============== =================================================================================
Tab             Views
=============== =================================================================================
Overview        accelerometer magnitude (raw vs calibrated), gyroscope magnitude, still blocks and
                segments lanes | summary (markdown) over the gravity arrows (3D)
Signals         accelerometer raw / calibrated axes, gyroscope raw / calibrated axes, detector
                statistic with its threshold (log10), blocks and segments lanes
Gravity         gravity arrows at the time cursor (3D) | angle measured-predicted per rotation
                (before/after), static block norm error (before/after), lanes
L-curve         the L-curve (2D, corner marked) | the lambda sweep: static norm error, log10 of
                lambda, rho and eta, the 9 accelerometer parameters (timeline ``lambda``)
Optimiser       cost and parameters at each accepted LM step (timeline ``iteration``)
Summary         the markdown summary, full size
=============== =================================================================================

Every plot opens on its whole x range (in Rerun 0.41 a plot linked to the global time axis
opens on a one-minute window instead, so the plots are not linked). A view only draws data on
the active timeline: the L-curve sweep and the optimiser views need the timeline ``lambda`` or
``iteration`` selected in the time panel (their titles say so); the layout opens on ``time``,
paused at its start.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import rerun.blueprint as rrb

from . import paths as P
from .guide import guide_column

if TYPE_CHECKING:
    from imucal.result import Result

TAB_NAMES = ("Overview", "Signals", "Gravity", "L-curve", "Optimiser", "Summary")


def _whole_axis() -> rrb.TimeAxis:
    return rrb.TimeAxis(view_range=rrb.TimeRange(start=rrb.TimeRangeBoundary.infinite(),
                                                 end=rrb.TimeRangeBoundary.infinite()))


def _ts(name: str, *contents: str) -> rrb.TimeSeriesView:
    return rrb.TimeSeriesView(name=name, origin="/", contents=list(contents),
                              axis_x=_whole_axis(),
                              plot_legend=rrb.PlotLegend(rrb.Corner2D.RightTop))


def _lanes() -> rrb.StateTimelineView:
    return rrb.StateTimelineView(name="Still blocks and segments", origin="/",
                                 contents=[P.DETECTOR_BLOCKS, P.DETECTOR_SEGMENTS],
                                 time_view=_whole_axis())


def _gravity3d() -> rrb.Spatial3DView:
    return rrb.Spatial3DView(
        name="Gravity at the cursor: measured green, predicted by raw gyro red, by calibrated "
             "gyro blue, previous grey",
        origin=P.GRAVITY, contents=[f"{P.GRAVITY}/**"],
        line_grid=rrb.LineGrid3D(visible=True, spacing=0.5),
        eye_controls=rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, position=[1.6, -2.0, 1.3],
                                       look_target=[0, 0, 0], eye_up=[0, 0, 1]))


def blueprint(result: Result | None = None, active_tab: int | str = 0) -> rrb.Blueprint:
    """The layout; ``result`` only decides which views there are (gyroscope, L-curve, fits).

    ``active_tab`` is the tab shown first: an index or a name from :data:`TAB_NAMES` (the
    L-curve tab exists only when lambda came from the L-curve).
    """
    gyro = result is None or (result.session.has_gyro and result.calibrated.gyro is not None)
    lcurve = result is None or result.whole.lcurve is not None
    fits = ["segment_0"] if result is None else (
        (["whole"] if len(result.segments) > 1 or result.segments[0].acc is not result.whole
         else []) + [f"segment_{s.index}" for s in result.segments])

    magnitudes = [_ts("Accelerometer magnitude: raw vs calibrated", P.ACC_MAGNITUDE)]
    if gyro:
        magnitudes.append(_ts("Gyroscope magnitude (rad/s): raw vs calibrated",
                              P.GYRO_MAGNITUDE))
    tabs: list[rrb.Container | rrb.View] = [rrb.Horizontal(
        rrb.Vertical(*magnitudes, _lanes(), row_shares=[3] * len(magnitudes) + [1]),
        rrb.Vertical(rrb.TextDocumentView(name="Summary", origin=P.SUMMARY), _gravity3d(),
                     row_shares=[3, 2]),
        guide_column(result), column_shares=[3, 2, 2], name="Overview")]

    signals = [_ts("Accelerometer axes, raw", P.ACC_RAW),
               _ts("Accelerometer axes, calibrated", P.ACC_CALIBRATED)]
    if gyro:
        signals += [_ts("Gyroscope axes, raw", P.GYRO_RAW),
                    _ts("Gyroscope axes, calibrated (rad/s)", P.GYRO_CALIBRATED)]
    signals.append(_ts("Static detector: log10 statistic (M1) and threshold",
                       P.DETECTOR_STATISTIC, P.DETECTOR_THRESHOLD))
    tabs.append(rrb.Vertical(*signals, _lanes(), row_shares=[2] * len(signals) + [1],
                             name="Signals"))

    block_errors = _ts("Static block norm error |mean a|/g − 1 (mg): before vs after",
                       P.BLOCK_ERROR_BEFORE, P.BLOCK_ERROR_AFTER)
    if gyro:
        tabs.append(rrb.Horizontal(
            _gravity3d(),
            rrb.Vertical(_ts("Gravity prediction error per rotation (deg): before vs after",
                             P.GRAVITY_ANGLE_BEFORE, P.GRAVITY_ANGLE_AFTER),
                         block_errors, _lanes(), row_shares=[2, 2, 1]),
            column_shares=[1, 1], name="Gravity"))
    else:
        tabs.append(rrb.Vertical(block_errors, _lanes(), row_shares=[3, 1], name="Gravity"))

    sweep = "(timeline 'lambda')"
    if lcurve:
        tabs.append(rrb.Horizontal(
            rrb.Spatial2DView(name="L-curve: residual norm ρ vs solution norm η (log-log), "
                                   "corner in red",
                              origin=P.LCURVE, contents=[f"{P.LCURVE}/**"]),
            rrb.Vertical(
                _ts(f"Static norm error vs λ (mg) {sweep}", P.LAMBDA_STATIC_RMS,
                    P.LAMBDA_STATIC_MAX, P.LAMBDA_CHOSEN),
                _ts(f"log10 of λ, ρ, η {sweep}", P.LAMBDA_LOG10, P.LAMBDA_RESIDUAL,
                    P.LAMBDA_SOLUTION),
                _ts(f"Misalignment vs λ (rad) {sweep}", P.LAMBDA_MISALIGNMENT),
                _ts(f"Scale vs λ {sweep}", P.LAMBDA_SCALE),
                _ts(f"Bias vs λ {sweep}", P.LAMBDA_BIAS)),
            column_shares=[1, 1], name="L-curve"))

    columns = []
    for sensor in ["accelerometer"] + (["gyroscope"] if gyro else []):
        views = [_ts(f"{sensor.capitalize()}: {label} per accepted step (timeline 'iteration')",
                     *[P.iteration(f, sensor, what) for f in fits])
                 for what, label in (("log10_cost", "log10 cost"),
                                     ("misalignment", "misalignment"), ("scale", "scale"),
                                     ("bias", "bias"))]
        columns.append(rrb.Vertical(*views))
    tabs.append(rrb.Horizontal(*columns, name="Optimiser"))
    tabs.append(rrb.TextDocumentView(name="Summary", origin=P.SUMMARY))

    if isinstance(active_tab, str):  # by name: tabs without data are left out
        names = [t.name for t in tabs]
        active_tab = names.index(active_tab) if active_tab in names else 0
    return rrb.Blueprint(
        rrb.Tabs(*tabs, active_tab=active_tab),
        rrb.TimePanel(timeline=P.TIME, state="collapsed", play_state="paused"),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        auto_layout=False, auto_views=False)
