"""``imucal check`` and ``imucal refresh`` as a Rerun recording (issue 26, item 5; method.md
§10): the still moments found on the recording's timeline, each figure moment by moment and as
it built up over the recording against its stored value and the band the check holds it to,
and what refresh changed.

=================================== ======== ===================================================
Entity path                          Timeline Content
=================================== ======== ===================================================
inuse/signals/acc_norm               time     Scalars ``|a|`` with the stored calibration (its
                                              last segment; calibrated unit), min/max envelope
                                              past ``SCREEN_ROWS``
inuse/signals/gyro_norm_deg_s        time     Scalars ``|w|`` calibrated, deg/s, the same
inuse/moments                        time     StateChange "still" at each moment's start, reset
                                              at its end (``Moments.times``)
inuse_norm/moment_mg                 time     Scalars M9's ``e_k`` (mg, signed) with the stored
                                              model, at each moment's middle
inuse_norm/refreshed_mg              time     the same with the refreshed model (refresh only,
                                              where it changed the accelerometer)
inuse_norm/rms_mg                    time     Scalars [RMS, 95 % low, 95 % high] over the
                                              moments up to each one, at its end
                                              (:func:`imucal.inuse.trace.running_norm`)
inuse_norm/expected_mg | limit_mg    time     2 rows each: what the stored calibration leads
                                              one to expect, the limit (``Part.expected``,
                                              ``Part.limit``)
inuse_gyro_<a>/moment_deg_s          time     Scalars [r, 95 % low, 95 % high] per moment (M10,
                                              axis a of the calibrated frame), at its middle
inuse_gyro_<a>/pooled_deg_s          time     Scalars [pooled, 95 % low, 95 % high] up to each
                                              moment (:func:`~imucal.inuse.trace.running_rate`)
inuse_gyro_<a>/band_deg_s            time     2 rows [-limit, stored (0), +limit]
refresh/<group>                      static   2D plot: x the parameter's axis, y its change
                                              (refreshed - stored) with 95 % bars; AnyValues
                                              parameter, stored, value, std_error
inuse/check | inuse/refresh          static   AnyValues: the verdict and figures; every
                                              parameter refreshed (sensor, parameter, stored,
                                              value, std_error, unit) and what was kept
inuse/note                           static   TextDocument (markdown): the verdict, the parts,
                                              the detector, what refresh changed and kept
=================================== ======== ===================================================

The gyroscope's rows exist only where the check judged a gyroscope, ``refresh/*`` and the
refreshed rows only for ``imucal refresh``. Every number is the check's or the refresh's
(:mod:`imucal.inuse`); this module lays them out.
"""

from __future__ import annotations

import os
import uuid
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from imucal.inuse.check import last_segment
from imucal.inuse.moments import ModelRows
from imucal.inuse.trace import moment_norm_mg, running_norm, running_rate
from imucal.io.atomic import atomic_path

from . import paths as P
from .columns import AFTER, BEFORE, CALIBRATED, GREY, MEASURED, STILL, XYZ, rgba, send_scalars
from .columns import style_lines as _lines
from .columns import style_points as _points
from .decimate import axes_cut
from .layout import Box
from .plot2d import Axis, Series, linear_axis, log_plot, to_scene
from .stream import EnvelopeStream

if TYPE_CHECKING:
    from imucal.inuse.check import Check
    from imucal.inuse.refresh import Refresh
    from imucal.session import Session
    from imucal.stages.apply import Calibration

AXES = "xyz"
READ_ROWS = 1 << 17  # rows calibrated at a time for the signals' envelopes
REFRESH_BOX = Box.fitting(955, 262, left=90, right=120)
BAND = 0x9E9E9EFF


def _group(e) -> tuple[str, str, float]:
    """A refreshed parameter's plot, the unit it is shown in and the factor to it."""
    if e.sensor == "gyroscope":
        return ("gyroscope_bias", "deg/s", float(np.degrees(1.0))) if e.unit == "rad/s" \
            else ("gyroscope_bias", e.unit, 1.0)
    if e.parameter.startswith("s_"):
        return "accelerometer_scale", "ppm", 1e6
    return ("accelerometer_bias", "mg", 1e3) if e.unit == "g" else (
        "accelerometer_bias", e.unit, 1.0)


def log_check(check: Check, cal: Calibration, session: Session, rec: rr.RecordingStream,
              refresh: Refresh | None = None) -> dict[str, int]:
    """Everything the check's (and refresh's) recording shows; returns the rows logged per
    temporal entity."""
    rows: dict[str, int] = {}
    seg, _, _ = last_segment(cal)
    _signals(session, seg, rec, rows)
    m = check.moments
    if m.count:
        times = m.times.ravel()
        rec.log(P.INUSE_MOMENTS, rr.StateConfiguration(values=["still"], labels=["still moment"],
                                                       colors=rgba([STILL])), static=True)
        rec.send_columns(P.INUSE_MOMENTS, indexes=[rr.TimeColumn(P.TIME, duration=times)],
                         columns=rr.StateChange.columns(state=["still", ""] * m.count))
        rows[P.INUSE_MOMENTS] = len(times)
    _norm(check, cal.g, rec, rows, refresh)
    _gyro(check, rec, rows)
    if refresh is not None:
        _refresh(refresh, rec)
    acc, gyro = check.parts
    rec.log(P.INUSE_CHECK, rr.AnyValues(
        verdict=check.level, exit_code=check.exit_code, reason=check.reason,
        moments=m.count, orientations=m.orientations,
        still_s=float(m.durations.sum()) if m.count else 0.0,
        acc_level=acc.level, acc_rms_mg=_nan(acc.value), acc_low_mg=_nan(acc.low),
        acc_high_mg=_nan(acc.high), acc_limit_mg=_nan(acc.limit),
        acc_expected_mg=_nan(acc.expected), gyro_level=gyro.level,
        gyro_limit_deg_s=_nan(gyro.limit)), static=True)
    rec.log(P.INUSE_NOTE, rr.TextDocument(check_note(check, refresh),
                                          media_type="text/markdown"), static=True)
    return rows


def _nan(x: float | None) -> float:
    return float("nan") if x is None else float(x)


def _signals(session: Session, seg, rec: rr.RecordingStream, rows: dict[str, int]) -> None:
    """The calibrated magnitudes, a chunk of rows at a time (a day's recording is never
    calibrated whole), as min/max envelopes."""
    parts = [(P.INUSE_ACC_NORM, session.acc, seg.acc, session.t_acc, 1.0, "|a|", CALIBRATED)]
    if session.has_gyro and seg.gyro is not None:
        parts.append((P.INUSE_GYRO_NORM, session.gyro, seg.gyro, session.t_gyro,
                      float(np.degrees(1.0)), "|w| (deg/s)", AFTER))
    for path, raw, model, t, scale, name, color in parts:
        t = np.asarray(t, float)
        stream = EnvelopeStream(t, axes_cut(len(t)))
        cal = ModelRows(raw, model)
        for a in range(0, len(t), READ_ROWS):
            stream.feed(np.linalg.norm(cal[a:a + READ_ROWS], axis=1) * scale)
        tt, vv, _ = stream.rows()
        rows[path] = send_scalars(rec, path, tt, vv)
        _lines(rec, path, [name], [color])


def _norm(check: Check, g: float, rec: rr.RecordingStream, rows: dict[str, int],
          refresh: Refresh | None) -> None:
    e = moment_norm_mg(check, g)
    if e is None:
        return
    mid = check.moments.times.mean(axis=1)
    rows[P.INUSE_NORM_MOMENT] = send_scalars(rec, P.INUSE_NORM_MOMENT, mid, e)
    _points(rec, P.INUSE_NORM_MOMENT, ["moment, stored model (mg)"], [BEFORE], size=3.0)
    fit = check.acc_fit
    if refresh is not None and fit is not None and fit.estimates:
        after = np.asarray(fit.errors_after, float) / g * 1e3
        rows[P.INUSE_NORM_REFRESHED] = send_scalars(rec, P.INUSE_NORM_REFRESHED, mid, after)
        _points(rec, P.INUSE_NORM_REFRESHED, ["moment, refreshed model (mg)"], [AFTER],
                size=3.0, marker="diamond")
    run = running_norm(check, g)
    if run is not None:
        rows[P.INUSE_NORM_RMS] = send_scalars(rec, P.INUSE_NORM_RMS, run.t, np.column_stack(
            [run.value, run.low, run.high]))
        _lines(rec, P.INUSE_NORM_RMS, ["RMS so far", "95 % low", "95 % high"],
               [CALIBRATED, BAND, BAND])
    acc = check.parts[0]
    ends = [check.moments.times[0, 0], check.moments.times[-1, 1]]
    for path, value, name in ((P.INUSE_NORM_EXPECTED, acc.expected, "expected (stored)"),
                              (P.INUSE_NORM_LIMIT, acc.limit, "limit")):
        if value is not None:
            rows[path] = send_scalars(rec, path, ends, np.full(2, value))
            _lines(rec, path, [f"{name} {value:.2f} mg"], [MEASURED if path ==
                                                          P.INUSE_NORM_EXPECTED else BEFORE])


def _gyro(check: Check, rec: rr.RecordingStream, rows: dict[str, int]) -> None:
    m = check.moments
    run = running_rate(check)
    gyro = check.parts[1]
    if run is None or gyro.limit is None:
        return
    mid = m.times.mean(axis=1)
    r, se = np.degrees(m.rate), np.degrees(m.rate_se)
    ends = [m.times[0, 0], m.times[-1, 1]]
    from imucal.inuse.check import Z95

    for i, a in enumerate(AXES):
        path = P.inuse_gyro(a, "moment_deg_s")
        rows[path] = send_scalars(rec, path, mid, np.column_stack(
            [r[:, i], r[:, i] - Z95 * se[:, i], r[:, i] + Z95 * se[:, i]]))
        rec.log(path, rr.SeriesPoints(names=["moment", "95 % low", "95 % high"],
                                      colors=rgba([XYZ[i], BAND, BAND]),
                                      markers=["circle", "up", "down"],
                                      marker_sizes=[3.0, 2.0, 2.0]), static=True)
        path = P.inuse_gyro(a, "pooled_deg_s")
        rows[path] = send_scalars(rec, path, run.t, np.column_stack(
            [run.value[:, i], run.low[:, i], run.high[:, i]]))
        _lines(rec, path, ["pooled so far", "95 % low", "95 % high"], [CALIBRATED, BAND, BAND])
        path = P.inuse_gyro(a, "band_deg_s")
        lim = gyro.limit
        rows[path] = send_scalars(rec, path, ends, np.tile([-lim, 0.0, lim], (2, 1)))
        _lines(rec, path, [f"-{lim:g}", "stored bias", f"+{lim:g}"], [BEFORE, GREY, BEFORE])


def _refresh(refresh: Refresh, rec: rr.RecordingStream) -> None:
    """Each refreshed parameter's change with its 95 % bar, a plot per kind (x its axis)."""
    groups: dict[str, list] = {}
    for e in refresh.changed:
        groups.setdefault(_group(e)[0], []).append(e)
    for name, es in groups.items():
        _, unit, k = _group(es[0])
        x = np.array([AXES.index(e.parameter[-1]) for e in es], float)
        d = np.array([e.change for e in es]) * k
        s = np.array([e.std_error for e in es]) * k * 1.959963984540054
        base = P.refresh_plot(name)
        xa = Axis(-0.5, 2.5, np.arange(3.0), [f"{name.split('_')[0][:5]} {a}" for a in AXES])
        ya = linear_axis(np.r_[d - s, d + s, 0.0], pad=0.12)
        ya = Axis(ya.lo, ya.hi, ya.ticks, [f"{t} {unit}" for t in ya.labels])
        log_plot(rec, base, REFRESH_BOX, xa, ya, [Series(
            "change", f"refreshed - stored ({unit})", AFTER, x, d, line=False, size=4.0,
            values={"parameter": [e.parameter for e in es],
                    "stored": np.array([e.stored for e in es]),
                    "value": np.array([e.value for e in es]),
                    "std_error": np.array([e.std_error for e in es]), "unit": [e.unit for e in es]},
            labels=[f"{e.parameter} {v:+.3g}" for e, v in zip(es, d)])])
        bars = [to_scene(REFRESH_BOX, xa, ya, [[xi, di - si], [xi, di + si]])
                for xi, di, si in zip(x, d, s)]
        bars.append(to_scene(REFRESH_BOX, xa, ya, [[xa.lo, 0.0], [xa.hi, 0.0]]))
        rec.log(f"{base}/bars", rr.LineStrips2D(bars, colors=rgba([AFTER] * len(es) + [GREY]),
                                                radii=rr.Radius.ui_points(1.0),
                                                draw_order=10.0), static=True)
    ch = refresh.changed
    rec.log(P.INUSE_REFRESH, rr.AnyValues(
        sensor=[e.sensor for e in ch] or [""], parameter=[e.parameter for e in ch] or [""],
        stored=np.array([e.stored for e in ch]), value=np.array([e.value for e in ch]),
        std_error=np.array([e.std_error for e in ch]), unit=[e.unit for e in ch] or [""],
        kept=list(refresh.kept) or [""], norm_before_mg=_nan(refresh.norm_before_mg),
        norm_after_mg=_nan(refresh.norm_after_mg)), static=True)


def check_note(check: Check, refresh: Refresh | None = None) -> str:
    """The note (markdown): the verdict, each part, the detector's choice, and for a refresh
    every parameter changed (stored, refreshed, standard error) and what was kept."""
    m = check.moments
    still = float(m.durations.sum()) if m.count else 0.0
    lines = [f"**{check.level}** (exit {check.exit_code}): {check.reason}", "",
             f"- {m.count} still moments, {still:.1f} s in all, {m.orientations} "
             f"orientation(s); detector window {m.window}, shortest {m.min_len} samples, "
             f"k {m.k:g} on {m.level_from}"]
    lines += [f"- {p.sensor}: {p.level}: {p.reason}" for p in check.parts]
    lines += [f"- {n}" for n in check.notes]
    if refresh is not None:
        lines += ["", "**Refresh**", ""]
        if refresh.changed:
            lines += ["| parameter | stored | refreshed | change | std error |",
                      "|---|---|---|---|---|"]
            lines += [f"| {e.sensor} {e.parameter} | {e.stored:.6g} | {e.value:.6g} | "
                      f"{e.change:+.3g} {e.unit} | {e.std_error:.2g} |" for e in refresh.changed]
        else:
            lines.append("nothing determined: nothing written")
        lines += [""] + [f"- kept: {k}" for k in refresh.kept]
        if refresh.norm_before_mg is not None:
            lines.append(f"- still-norm RMS {refresh.norm_before_mg:.2f} mg stored, "
                         f"{refresh.norm_after_mg:.2f} mg refreshed")
    return "\n".join(lines)


# --- the layout ---------------------------------------------------------------------------------


def _whole_axis() -> rrb.TimeAxis:
    return rrb.TimeAxis(view_range=rrb.TimeRange(start=rrb.TimeRangeBoundary.infinite(),
                                                 end=rrb.TimeRangeBoundary.infinite()))


def _ts(name: str, *contents: str) -> rrb.TimeSeriesView:
    return rrb.TimeSeriesView(name=name, origin="/", contents=list(contents),
                              axis_x=_whole_axis(), plot_legend=rrb.PlotLegend(visible=False))


def check_blueprint(check: Check, refresh: Refresh | None = None,
                    acc_unit: str = "g") -> rrb.Blueprint:
    """The Check tab (signals, the still-norm error and the gyroscope's rate at rest per axis
    over the recording, the moments as a lane, the note) and, for a refresh, the Refresh tab
    (each parameter's change with its 95 % bar, the note)."""
    acc, gyro = check.parts
    band = "" if acc.limit is None else f", limit {acc.limit:.2f} red, expected green"
    rows: list = [
        rrb.Horizontal(_ts(f"|a| with the stored calibration ({acc_unit})", P.INUSE_ACC_NORM),
                       *([_ts("|w| calibrated (deg/s)", P.INUSE_GYRO_NORM)]
                         if gyro.limit is not None else [])),
        _ts("Still-norm error per moment (mg, red ●; refreshed blue ◆) and its RMS so far "
            f"(blue) with 95 % band (grey){band}", P.INUSE_NORM_MOMENT, P.INUSE_NORM_REFRESHED,
            P.INUSE_NORM_RMS, P.INUSE_NORM_EXPECTED, P.INUSE_NORM_LIMIT)]
    shares = [1.0, 1.4]
    if gyro.limit is not None and check.moments.rate is not None:
        rows.append(rrb.Horizontal(*[_ts(
            f"Gyro {a}: rate at rest (deg/s), pooled blue, ±{gyro.limit:g} red",
            P.inuse_gyro(a, "moment_deg_s"), P.inuse_gyro(a, "pooled_deg_s"),
            P.inuse_gyro(a, "band_deg_s")) for a in AXES]))
        shares.append(1.4)
    rows.append(rrb.StateTimelineView(name="Still moments", origin="/",
                                      contents=[P.INUSE_MOMENTS], time_view=_whole_axis()))
    shares.append(0.45)
    tabs = [rrb.Horizontal(rrb.Vertical(*rows, row_shares=shares),
                           rrb.TextDocumentView(name="Check", origin=P.INUSE_NOTE),
                           column_shares=[3, 1], name="Check")]
    if refresh is not None:
        groups = []
        for e in refresh.changed:
            g = _group(e)
            if g[0] not in [x[0] for x in groups]:
                groups.append(g)
        plots = [rrb.Spatial2DView(
            name=f"{name.replace('_', ' ').capitalize()}: refreshed − stored ({unit}), 95 % bars",
            origin=P.refresh_plot(name), contents=[f"{P.refresh_plot(name)}/**"],
            visual_bounds=rrb.VisualBounds2D(x_range=REFRESH_BOX.bounds()[0],
                                             y_range=REFRESH_BOX.bounds()[1]))
            for name, unit, _ in groups]
        note = rrb.TextDocumentView(name="Refresh", origin=P.INUSE_NOTE)
        tabs.append(rrb.Horizontal(rrb.Vertical(*plots), note, column_shares=[3, 2],
                                   name="Refresh") if plots else rrb.Horizontal(
                                       note, name="Refresh"))
    # One tab alone is no Tabs container: the viewer drops such a container and lays out
    # every entity by itself instead (measured, Rerun 0.41).
    return rrb.Blueprint(
        rrb.Tabs(*tabs, active_tab=0) if len(tabs) > 1 else tabs[0],
        rrb.TimePanel(timeline=P.TIME, state="collapsed", play_state="paused"),
        rrb.BlueprintPanel(state="collapsed"), rrb.SelectionPanel(state="collapsed"),
        auto_layout=False, auto_views=False)


def save_check_recording(check: Check, cal: Calibration, session: Session,
                         path: str | os.PathLike | BinaryIO, refresh: Refresh | None = None
                         ) -> dict[str, int]:
    """Write the check's (or refresh's) recording with its layout as one ``.rrd``: to
    ``path`` atomically, or to an open binary file (a command's transaction owns the
    rename). Returns the rows logged per temporal entity."""
    if not hasattr(path, "write"):
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            return save_check_recording(check, cal, session, f, refresh)
    from .rrd_file import rrd_sink

    rec = rr.RecordingStream(P.APPLICATION_ID, recording_id=uuid.uuid4())
    with rrd_sink(rec, path, default_blueprint=check_blueprint(check, refresh, cal.acc_unit)):
        rec.send_recording_name(("refresh " if refresh is not None else "check ")
                                + (Path(session.source).name or "recording"))
        return log_check(check, cal, session, rec, refresh)
