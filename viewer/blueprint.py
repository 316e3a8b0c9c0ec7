"""The layout stored in every recording: tabs that need no arranging, every view with data the
moment its tab opens.

=============== =================================================================================
Tab             Views
=============== =================================================================================
Overview        accelerometer magnitude (raw vs calibrated, robust y range), the rotation error
                per turn and |ā|/g − 1 per still block, before vs after on log axes (the
                evidence: viewer.evidence), still blocks and segments lanes | summary
                (markdown) over every block's gravity arrows (3D) | the guide
Signals         accelerometer raw | gyroscope raw over accelerometer calibrated | gyroscope
                calibrated, detector statistic with its threshold (log10), lanes
Gravity         gravity arrows at the time cursor (3D) | angle measured-predicted per rotation and
                static block norm error, each before vs after and after alone, lanes
L-curve         static norm error and the 9 accelerometer parameters against lambda (2D plots)
                | the L-curve (its corner, or "no corner" when the fit is well posed)
Optimiser       cost and parameters at each accepted step, one column per sensor (2D plots)
Magnetometer    (a calibrated magnetometer only) raw field with the fitted ellipsoid | calibrated
                field on its sphere, over the norm |m|/F − 1 and the dip per still block
                against time, still blocks and disturbed parts as lanes | the note
Triads          (other triads only) per triad, each shared block's gravity difference (mg)
                before, calibrated, rotated, held out, over the lanes | figures side by side
Temperature     (a bias in temperature only) accelerometer bias, block norm error (and scale)
                vs temperature | gyroscope bias per axis vs temperature | temperature over
                time, lanes, the note
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

import rerun.blueprint as rrb

from . import paths as P
from .evidence import evidence_titles
from .guide import guide_column
from .layout import (
    EVIDENCE_BOX,
    LCURVE_BOX,
    MAG_LCURVE_BOX,
    SWEEP_BOX,
    TRACE_BOX,
    TRACE_BOX_WIDE,
    Box,
)
from .magnetometer import mag_titles
from .optimiser import WHATS, cost_title
from .ranges import robust_range
from .signal_rows import SignalRows, signal_rows
from .temperature import temperature_tab
from .triads import triads_tab

__all__ = ["TAB_NAMES", "blueprint", "robust_range"]

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


def _gravity3d(name: str, every_block: bool = False) -> rrb.Spatial3DView:
    """The gravity arrows at the time cursor; ``every_block``: every block's at once (the
    layout opens at the start, where block 0 has no prediction: one arrow, nothing to
    compare), the previous block's grey arrows left out."""
    extra = {}
    if every_block:
        extra["time_ranges"] = [rrb.VisibleTimeRange(
            P.TIME, start=rrb.TimeRangeBoundary.infinite(),
            end=rrb.TimeRangeBoundary.infinite())]
    return rrb.Spatial3DView(
        name=name, origin=P.GRAVITY, **extra,
        contents=[f"{P.GRAVITY}/**"] + ([f"- {P.GRAVITY_PREVIOUS}"] if every_block else []),
        line_grid=rrb.LineGrid3D(visible=False),
        eye_controls=rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, position=[1.05, -1.35, 0.85],
                                       look_target=[0, 0, 0], eye_up=[0, 0, 1]))


def _plot2d(name: str, origin: str, box: Box) -> rrb.Spatial2DView:
    x, y = box.bounds()
    return rrb.Spatial2DView(name=name, origin=origin, contents=[f"{origin}/**"],
                             visual_bounds=rrb.VisualBounds2D(x_range=x, y_range=y))


def _overview(result: Result | None, signals: SignalRows | None, gyro: bool
              ) -> rrb.Horizontal:
    """The accelerometer's magnitude (raw vs calibrated), then the evidence per turn and per
    still block, before vs after on log axes (:mod:`viewer.evidence`: the gyroscope's raw and
    calibrated magnitudes overlap, so they show nothing of its calibration), over the lanes;
    the summary over the gravity arrows; the guide."""
    acc_unit = "" if result is None else f" ({result.calibration.acc_unit})"
    acc_range = None if signals is None else signals.acc.y_range
    turns_title, blocks_title = evidence_titles(result)
    rows: list[rrb.View] = [_ts(f"Accelerometer magnitude{acc_unit}: raw (orange, nominal "
                                "scale) vs calibrated (blue)", P.ACC_MAGNITUDE,
                                y_range=acc_range)]
    if gyro:
        rows.append(_plot2d(turns_title, P.EVIDENCE_TURNS, EVIDENCE_BOX))
    rows.append(_plot2d(blocks_title, P.EVIDENCE_BLOCKS, EVIDENCE_BOX))
    return rrb.Horizontal(
        _with_lanes(*rows),
        rrb.Vertical(rrb.TextDocumentView(name="Summary", origin=P.SUMMARY),
                     _gravity3d("Gravity per block: green measured, red/blue predicted",
                                every_block=True),
                     row_shares=[3, 2]),
        guide_column(result), column_shares=[3, 2, 2], name="Overview")


def _signals(result: Result | None, signals: SignalRows | None, gyro: bool) -> rrb.Vertical:
    acc_raw = "" if result is None else f" ({result.session.acc_unit})"
    acc_cal = "" if result is None else f" ({result.calibration.acc_unit})"
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
    detector_range = None if signals is None else signals.detector_range
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
    """What each λ gives (the error first, then the parameters) on the left, the L-curve on
    the right; when the fit is well posed (``LCurve.well_posed``: no L, every λ up to some
    value gives the same fit) the titles say so instead of naming a corner."""
    unit = "raw unit" if result is None else result.session.acc_unit
    lc = None if result is None else result.whole.lcurve
    if lc is not None and lc.well_posed:
        same = f"{lc.lambdas[lc.same_fit_until]:.3g}"
        curve_title = (f"L-curve ρ vs η (log-log): no corner, the fit is well posed: every "
                       f"λ up to {same} gives the same fit")
        static_title = (f"Static norm error (mg, log) vs λ: RMS and max over the still "
                        f"blocks; all λ below {same} give the same fit")
    else:
        curve_title = "L-curve: residual norm ρ vs solution norm η (log-log), corner in red"
        static_title = "Static norm error (mg, log scale) vs λ: RMS and max over the still blocks"
    curve = _plot2d(curve_title, P.LCURVE, LCURVE_BOX)
    if result is not None and result.whole.sweep is None:
        return rrb.Horizontal(curve, name="L-curve")
    return rrb.Horizontal(
        rrb.Vertical(
            _plot2d(static_title, P.LAMBDA_STATIC, SWEEP_BOX),
            _plot2d("Accelerometer misalignment (rad) vs λ", P.LAMBDA_MISALIGNMENT, SWEEP_BOX),
            _plot2d("Accelerometer scale vs λ", P.LAMBDA_SCALE, SWEEP_BOX),
            _plot2d(f"Accelerometer bias ({unit}) vs λ", P.LAMBDA_BIAS, SWEEP_BOX)),
        curve,
        column_shares=[1, 1], name="L-curve")


def _optimiser(result: Result | None, gyro: bool) -> rrb.Horizontal:
    box = TRACE_BOX if gyro else TRACE_BOX_WIDE

    def title(sensor: str, what: str) -> str:
        if what == "log10_cost":
            return cost_title(result, sensor)
        return f"{sensor.capitalize()}: {what} per accepted step of the optimiser"

    columns = [rrb.Vertical(*[_plot2d(title(sensor, what), P.iteration(sensor, what), box)
                              for what in WHATS])
               for sensor in ["accelerometer"] + (["gyroscope"] if gyro else [])]
    return rrb.Horizontal(*columns, name="Optimiser")


def _scene3d(name: str, origin: str) -> rrb.Spatial3DView:
    return rrb.Spatial3DView(name=name, origin=origin, contents=[f"{origin}/**"],
                             line_grid=rrb.LineGrid3D(visible=False),
                             eye_controls=rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital))


def _magnetometer(result: Result) -> rrb.Horizontal:
    """The raw field with the fitted ellipsoid and the calibrated field on its sphere, over
    the norm and the dip per still block against time with the still blocks and the disturbed
    parts as lanes; the note (figures, coverage, what was left out) beside
    (:mod:`viewer.magnetometer`)."""
    raw_title, cal_title = mag_titles(result)
    lanes = rrb.StateTimelineView(name="Still blocks (green), disturbed field (red: norm, "
                                  "orange: dip, purple: step)", origin="/",
                                  contents=[P.DETECTOR_BLOCKS, P.MAG_DISTURBED],
                                  time_view=_whole_axis())
    return rrb.Horizontal(
        rrb.Vertical(
            rrb.Horizontal(_scene3d(raw_title, P.MAG_RAW), _scene3d(cal_title, P.MAG_CALIBRATED)),
            _ts("Field norm |m|/F − 1 (%): used blue, left out red",
                P.MAG_NORM_USED, P.MAG_NORM_LEFT_OUT),
            _ts("Dip per still block (deg): used blue, left out red; fitted grey",
                P.MAG_DIP_USED, P.MAG_DIP_LEFT_OUT, P.MAG_DIP_FIT),
            lanes, row_shares=[3.0, 1.2, 1.2, 0.8]),
        _mag_side(result),
        column_shares=[4, 1], name="Magnetometer")


def _mag_side(result: Result) -> rrb.Container | rrb.View:
    """The note, over the small L-curve of the soft iron's Tikhonov term (M8r) when fitted."""
    note = rrb.TextDocumentView(name="Magnetometer", origin=P.MAG_NOTE)
    fit = result.magnetometer
    if fit is None or fit.lcurve is None:
        return note
    what = "no corner: the data determine it" if fit.lcurve.well_posed else "corner in red"
    return rrb.Vertical(note, _plot2d(f"Soft iron L-curve: ρ vs η (log-log), {what}",
                                      P.MAG_LCURVE, MAG_LCURVE_BOX), row_shares=[1, 1])


def blueprint(result: Result | None = None, active_tab: int | str = 0,
              signals: SignalRows | None = None) -> rrb.Blueprint:
    """The layout; ``result`` decides which views there are (gyroscope, L-curve, before) and
    the ranges and units the titles and axes show (the ranges are ``signals``'s, made from
    ``result`` when not given: :func:`~viewer.signal_rows.signal_rows`).

    ``active_tab`` is the tab shown first: an index or a name from :data:`TAB_NAMES` (the
    L-curve tab exists only when lambda came from the L-curve).
    """
    if result is not None and signals is None:
        signals = signal_rows(result)
    gyro = result is None or result.calibration.applies_gyro(result.session)
    lcurve = result is None or result.whole.lcurve is not None
    tabs: list[rrb.Container | rrb.View] = [_overview(result, signals, gyro),
                                            _signals(result, signals, gyro),
                                            _gravity(result, gyro)]
    if lcurve:
        tabs.append(_lcurve(result))
    tabs.append(_optimiser(result, gyro))
    if result is not None and result.magnetometer is not None:
        tabs.append(_magnetometer(result))
    if result is not None and result.triads:
        tabs.append(triads_tab(result, _whole_axis, _lanes))
    if result is not None and result.temperature:
        tabs.append(temperature_tab(result, _whole_axis, _lanes))
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
