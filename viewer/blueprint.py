"""The layout stored in every recording: tabs that need no arranging, every view with data the
moment its tab opens.

=============== =================================================================================
Tab             Views
=============== =================================================================================
Overview        accelerometer magnitude (raw vs calibrated, robust y range), gyroscope magnitude,
                still blocks and segments lanes | summary (markdown) over the gravity arrows (3D)
Signals         accelerometer raw | gyroscope raw over accelerometer calibrated | gyroscope
                calibrated, detector statistic with its threshold (log10), lanes
Gravity         gravity arrows at the time cursor (3D) | angle measured-predicted per rotation and
                static block norm error, each before vs after and after alone, lanes
L-curve         the L-curve (corner marked) | static norm error and the 9 accelerometer
                parameters against lambda (2D plots)
Optimiser       cost and parameters at each accepted step, one column per sensor (2D plots)
Summary         the markdown summary, full size
=============== =================================================================================

Every time plot opens on its whole x range (in Rerun 0.41 a plot linked to the global time axis
opens on a one-minute window instead, so the plots are not linked); the layout opens on
``time``, paused at its start. A TimeSeriesView plots against the time panel's timeline only,
so what runs against lambda or the optimiser's step is drawn as 2D plots with their own axes
(:mod:`viewer.plot2d`, sizes in :mod:`viewer.layout`). Legends are off: each title names its
colours, so no legend covers the end of a curve.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import rerun.blueprint as rrb

from . import paths as P
from .guide import guide_column
from .layout import LCURVE_BOX, SWEEP_BOX, TRACE_BOX, TRACE_BOX_WIDE, Box
from .optimiser import WHATS

if TYPE_CHECKING:
    from imucal.result import Result

TAB_NAMES = ("Overview", "Signals", "Gravity", "L-curve", "Optimiser", "Summary")
LANES_PX = 135  # a lanes view's height: its time axis and two lanes, with the title bar
TAB_PX = 905  # the height a tab's views share at the default window size
XYZ_KEY = "x red, y green, z blue"


def _whole_axis() -> rrb.TimeAxis:
    return rrb.TimeAxis(view_range=rrb.TimeRange(start=rrb.TimeRangeBoundary.infinite(),
                                                 end=rrb.TimeRangeBoundary.infinite()))


def _ts(name: str, *contents: str, y_range: tuple[float, float] | None = None
        ) -> rrb.TimeSeriesView:
    axis_y = None if y_range is None else rrb.ScalarAxis(range=y_range)
    return rrb.TimeSeriesView(name=name, origin="/", contents=list(contents),
                              axis_x=_whole_axis(), axis_y=axis_y,
                              plot_legend=rrb.PlotLegend(visible=False))


def _lanes() -> rrb.StateTimelineView:
    return rrb.StateTimelineView(name="Still blocks (green) and segments", origin="/",
                                 contents=[P.DETECTOR_BLOCKS, P.DETECTOR_SEGMENTS],
                                 time_view=_whole_axis())


def _with_lanes(*views: rrb.Container | rrb.View, shares: list[float] | None = None,
                **kw) -> rrb.Vertical:
    """``views`` stacked over the lanes, which get :data:`LANES_PX` whatever the rest takes."""
    shares = shares or [1.0] * len(views)
    lanes = sum(shares) * LANES_PX / (TAB_PX - LANES_PX)
    return rrb.Vertical(*views, _lanes(), row_shares=[*shares, lanes], **kw)


def _row(*views: rrb.Container | rrb.View) -> rrb.Container | rrb.View:
    """Views side by side; one view alone (the viewer would fold a container of one)."""
    return views[0] if len(views) == 1 else rrb.Horizontal(*views)


def _gravity3d(name: str) -> rrb.Spatial3DView:
    return rrb.Spatial3DView(
        name=name, origin=P.GRAVITY, contents=[f"{P.GRAVITY}/**"],
        line_grid=rrb.LineGrid3D(visible=False),
        eye_controls=rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, position=[1.05, -1.35, 0.85],
                                       look_target=[0, 0, 0], eye_up=[0, 0, 1]))


def _plot2d(name: str, origin: str, box: Box) -> rrb.Spatial2DView:
    x, y = box.bounds()
    return rrb.Spatial2DView(name=name, origin=origin, contents=[f"{origin}/**"],
                             visual_bounds=rrb.VisualBounds2D(x_range=x, y_range=y))


def robust_range(values: np.ndarray, q: float = 0.005, pad: float = 0.08
                 ) -> tuple[float, float] | None:
    """A y range that holds all but the ``q`` most extreme samples at each end: one spike
    (a knock, a glitch) must not squash the rest of the plot into a line."""
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    if len(v) < 2:
        return None
    lo, hi = np.quantile(v, [q, 1.0 - q])
    if not hi > lo:
        return None
    return float(lo - pad * (hi - lo)), float(hi + pad * (hi - lo))


def _overview(result: Result | None, gyro: bool) -> rrb.Horizontal:
    acc_unit = "" if result is None else f" ({result.calibrated.acc_unit})"
    acc_range = None if result is None else robust_range(
        np.concatenate([result.raw_acc_norm, result.calibrated.acc_norm]))
    magnitudes = [_ts(f"Accelerometer magnitude{acc_unit}: raw (orange, nominal scale) vs "
                      "calibrated (blue)", P.ACC_MAGNITUDE, y_range=acc_range)]
    if gyro:
        gyro_range = None if result is None else robust_range(
            np.concatenate([result.raw_gyro_norm, result.calibrated.gyro_norm]), q=0.0005)
        magnitudes.append(_ts("Gyroscope magnitude (rad/s): raw (orange, nominal scale) vs "
                              "calibrated (blue)", P.GYRO_MAGNITUDE, y_range=gyro_range))
    return rrb.Horizontal(
        _with_lanes(*magnitudes),
        rrb.Vertical(rrb.TextDocumentView(name="Summary", origin=P.SUMMARY),
                     _gravity3d("Gravity: green measured, red/blue predicted"),
                     row_shares=[3, 2]),
        guide_column(result), column_shares=[3, 2, 2], name="Overview")


def _signals(result: Result | None, gyro: bool) -> rrb.Vertical:
    acc_raw = "" if result is None else f" ({result.session.acc_unit})"
    acc_cal = "" if result is None else f" ({result.calibrated.acc_unit})"
    acc = [_ts(f"Accelerometer axes, raw{acc_raw}: {XYZ_KEY}", P.ACC_RAW),
           _ts(f"Accelerometer axes, calibrated{acc_cal}: {XYZ_KEY}", P.ACC_CALIBRATED)]
    if gyro:
        gyro_raw = "" if result is None else f" ({result.session.gyro_unit})"
        grid: rrb.Container = rrb.Horizontal(
            rrb.Vertical(*acc),
            rrb.Vertical(_ts(f"Gyroscope axes, raw{gyro_raw}: {XYZ_KEY}", P.GYRO_RAW),
                         _ts(f"Gyroscope axes, calibrated (rad/s): {XYZ_KEY}",
                             P.GYRO_CALIBRATED)))
    else:
        grid = rrb.Vertical(*acc)
    detector_range = None
    if result is not None:  # M1 is not kept in the result: computed again, a span at a time
        stat = result.detection.statistic(result.session.acc)
        detector_range = robust_range(np.append(np.log10(stat[stat > 0]),
                                                np.log10(result.detection.threshold)), q=0.0)
    detector = _ts("Static detector (M1): log10 statistic (blue) and threshold (red)",
                   P.DETECTOR_STATISTIC, P.DETECTOR_THRESHOLD, y_range=detector_range)
    return _with_lanes(grid, detector, shares=[1.8, 1.0], name="Signals")


def _gravity(result: Result | None, gyro: bool) -> rrb.Container:
    before = result is None or result.quality.block_norm_error_before_mg is not None
    # Short titles: a view's title is cut at its width (half of a half of the window here).
    norm = [_ts("Block |ā|/g − 1 (mg): before red, after blue"
                if before else "Block |ā|/g − 1 (mg), calibrated",
                P.BLOCK_ERROR_BEFORE, P.BLOCK_ERROR_AFTER)]
    if before:
        norm.append(_ts("Block |ā|/g − 1 after (mg)", P.BLOCK_ERROR_AFTER))
    if not gyro:
        return _with_lanes(_row(*norm), name="Gravity")
    angle_before = result is None or any(
        s.gyro is not None and s.gyro.u_pred_before is not None for s in result.segments)
    angle = [_ts("Rotation error (deg): before red, after blue"
                 if angle_before else "Rotation error (deg), calibrated",
                 P.GRAVITY_ANGLE_BEFORE, P.GRAVITY_ANGLE_AFTER)]
    if angle_before:
        angle.append(_ts("Rotation error after (deg)", P.GRAVITY_ANGLE_AFTER))
    return rrb.Horizontal(
        _gravity3d("Gravity: measured green, previous grey, predicted red (raw gyro), "
                   "blue (calibrated)"),
        _with_lanes(_row(*angle), _row(*norm)),
        column_shares=[1, 1], name="Gravity")


def _lcurve(result: Result | None) -> rrb.Container:
    unit = "raw unit" if result is None else result.session.acc_unit
    curve = _plot2d("L-curve: residual norm ρ vs solution norm η (log-log), corner in red",
                    P.LCURVE, LCURVE_BOX)
    if result is not None and result.whole.sweep is None:
        return rrb.Horizontal(curve, name="L-curve")
    return rrb.Horizontal(
        curve,
        rrb.Vertical(
            _plot2d("Static norm error (mg, log scale) vs λ: RMS and max over the still blocks",
                    P.LAMBDA_STATIC, SWEEP_BOX),
            _plot2d("Accelerometer misalignment (rad) vs λ", P.LAMBDA_MISALIGNMENT, SWEEP_BOX),
            _plot2d("Accelerometer scale vs λ", P.LAMBDA_SCALE, SWEEP_BOX),
            _plot2d(f"Accelerometer bias ({unit}) vs λ", P.LAMBDA_BIAS, SWEEP_BOX)),
        column_shares=[1, 1], name="L-curve")


def _optimiser(gyro: bool) -> rrb.Horizontal:
    box = TRACE_BOX if gyro else TRACE_BOX_WIDE
    labels = {"log10_cost": "cost (log scale)", "misalignment": "misalignment",
              "scale": "scale", "bias": "bias"}
    columns = [rrb.Vertical(*[_plot2d(f"{sensor.capitalize()}: {labels[what]} per accepted "
                                      "step of the optimiser", P.iteration(sensor, what), box)
                              for what in WHATS])
               for sensor in ["accelerometer"] + (["gyroscope"] if gyro else [])]
    return rrb.Horizontal(*columns, name="Optimiser")


def blueprint(result: Result | None = None, active_tab: int | str = 0) -> rrb.Blueprint:
    """The layout; ``result`` decides which views there are (gyroscope, L-curve, before) and
    the ranges and units the titles and axes show.

    ``active_tab`` is the tab shown first: an index or a name from :data:`TAB_NAMES` (the
    L-curve tab exists only when lambda came from the L-curve).
    """
    gyro = result is None or (result.session.has_gyro and result.calibrated.gyro is not None)
    lcurve = result is None or result.whole.lcurve is not None
    tabs: list[rrb.Container | rrb.View] = [_overview(result, gyro), _signals(result, gyro),
                                            _gravity(result, gyro)]
    if lcurve:
        tabs.append(_lcurve(result))
    tabs.append(_optimiser(gyro))
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
