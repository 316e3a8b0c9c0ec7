"""The fleet as Rerun recordings: a device's drift on a ``calibrated_at`` timeline, and the
fleet report (each parameter's robust z per device, the outliers the fleet's test found
flagged: :mod:`imucal.fleet.drift`) a QA engineer opens.

Everything logged is :mod:`imucal.fleet.drift`'s; this module only lays it out (positions in
the 2D plot, clipping for display, labels, markdown).

=============================================== ============= ==================================
Entity path                                      Timeline      Content
=============================================== ============= ==================================
drift/<sensor>/<group>/<device>/<name>           calibrated_at Scalars: the parameter in each
                                                               calibration (raw units; sensor
                                                               accelerometer | gyroscope, group
                                                               misalignment | scale | bias)
drift/quality/<figure>/<device>                  calibrated_at Scalars: static_norm_rms_mg_after,
                                                               ..._cv, gravity_angle_rms_deg_...
drift/stats/<device>                             static        AnyValues: parameter, unit, change,
                                                               per_30d, change_sigma (one per
                                                               parameter), calibrated_at, path
drift/summary                                    static        TextDocument (markdown): the table
fleet/z/points                                   static        Points2D at (parameter index, -z
                                                               clipped to +-Z_SHOWN), the outliers
                                                               red and labelled; AnyValues
                                                               device, parameter, value, z
fleet/z/frame                                    static        the zero line and the parameter
                                                               names
fleet/parameters/<sensor>/<name>                 static        AnyValues: unit, devices, values,
                                                               z, median, mad, z_from, outliers
fleet/outliers                                   static        AnyValues: count, and device,
                                                               parameter, unit, value, z, path
fleet/report                                     static        TextDocument (markdown)
=============================================== ============= ==================================
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Callable

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from imucal.fleet.drift import ESD_ALPHA, QUALITY, DeviceDrift, FleetReport
from imucal.fleet.index import iso
from imucal.io.atomic import atomic_path

from .columns import BEFORE, GREY, SEGMENT_COLORS, rgba

CALIBRATED_AT = "calibrated_at"  # timestamp timeline: when each calibration was made
Z_SHOWN = 12.0  # robust z beyond this is drawn at the edge (its label says how far)
_MARKERS = ("circle", "diamond", "square", "up", "down", "cross", "asterisk", "plus")
_SENSORS = ("accelerometer", "gyroscope")
_GROUPS = ("misalignment", "scale", "bias")
QUALITY_TITLES = {  # method.md §5
    "static_norm_rms_mg_after": "static norm error after calibration, RMS (mg)",
    "static_norm_rms_mg_cv": "static norm error, each block held out (mg)",
    "gravity_angle_rms_deg_after": "gravity prediction error after calibration, RMS (deg)",
    "gravity_angle_rms_deg_cv": "gravity prediction error, held out (deg)"}


def _save(path: str | os.PathLike, name: str, layout: rrb.Blueprint,
          log: Callable[[rr.RecordingStream], None]) -> None:
    """One .rrd, written atomically (a temporary file beside it, then a rename)."""
    with atomic_path(path) as tmp:
        rec = rr.RecordingStream("imucal", recording_id=uuid.uuid4())
        rec.save(tmp, default_blueprint=layout)
        rec.send_recording_name(name)
        log(rec)
        rec.flush()
        rec.disconnect()  # closes the file sink: the footer is written before the rename
        del rec


def _whole_axis() -> rrb.TimeAxis:
    return rrb.TimeAxis(view_range=rrb.TimeRange(start=rrb.TimeRangeBoundary.infinite(),
                                                 end=rrb.TimeRangeBoundary.infinite()))


def _panels(timeline: str | None = None) -> list:
    return [rrb.TimePanel(timeline=timeline, state="collapsed", play_state="paused"),
            rrb.BlueprintPanel(state="collapsed"), rrb.SelectionPanel(state="collapsed")]


# --- drift ---------------------------------------------------------------------------------------


def drift_path(sensor: str, group: str, device: str, name: str) -> str:
    return f"drift/{sensor}/{group}/{device}/{name}"


def save_drift(drifts: list[DeviceDrift], path: str | os.PathLike) -> None:
    """The drift of one or more devices, each parameter on the ``calibrated_at`` timeline."""
    names = ", ".join(d.device for d in drifts)
    _save(path, f"drift {names}", _drift_blueprint(drifts),
          lambda rec: _log_drift(rec, drifts))


def _log_drift(rec: rr.RecordingStream, drifts: list[DeviceDrift]) -> None:
    for k, d in enumerate(drifts):
        when = rr.TimeColumn(CALIBRATED_AT, timestamp=np.array(
            [t.replace(tzinfo=None) for t in d.times], dtype="datetime64[us]"))
        marker = _MARKERS[k % len(_MARKERS)]
        for p in d.params:
            entity = drift_path(p.param.sensor, p.param.group, d.device, p.param.name)
            rec.send_columns(entity, indexes=[when],
                             columns=rr.Scalars.columns(scalars=p.values))
            axis = [q.param.name for q in d.params
                    if (q.param.sensor, q.param.group) == (p.param.sensor, p.param.group)]
            color = rgba([SEGMENT_COLORS[axis.index(p.param.name) % len(SEGMENT_COLORS)]])
            unit = "" if p.unit == "1" else f" ({p.unit})"
            label = [f"{d.device} {p.param.name}{unit}"]
            rec.log(entity, rr.SeriesLines(names=label, colors=color),
                    rr.SeriesPoints(names=label, colors=color, markers=[marker],
                                    marker_sizes=[5.0]), static=True)
        for q in QUALITY:
            if np.isfinite(d.quality[q]).any():
                entity = f"drift/quality/{q}/{d.device}"
                rec.send_columns(entity, indexes=[when],
                                 columns=rr.Scalars.columns(scalars=d.quality[q]))
                label = [f"{d.device} {QUALITY_TITLES[q]}"]
                rec.log(entity, rr.SeriesLines(names=label),
                        rr.SeriesPoints(names=label, markers=[marker], marker_sizes=[5.0]),
                        static=True)
        rec.log(f"drift/stats/{d.device}", rr.AnyValues(
            parameter=[p.param.label for p in d.params], unit=[p.unit for p in d.params],
            change=np.array([p.change for p in d.params]),
            per_30d=np.array([p.per_30d for p in d.params]),
            change_sigma=np.array([p.change_sigma for p in d.params]),
            calibrated_at=[iso(t) for t in d.times], path=d.paths), static=True)
    rec.log("drift/summary", rr.TextDocument(_drift_markdown(drifts),
                                             media_type=rr.MediaType.MARKDOWN), static=True)


def _drift_blueprint(drifts: list[DeviceDrift]) -> rrb.Blueprint:
    have = {(p.param.sensor, p.param.group) for d in drifts for p in d.params}
    tabs = []
    for sensor in _SENSORS:
        views = [rrb.TimeSeriesView(name=f"{sensor.capitalize()} {group} per calibration",
                                    origin="/", contents=[f"drift/{sensor}/{group}/**"],
                                    axis_x=_whole_axis())
                 for group in _GROUPS if (sensor, group) in have]
        if views:
            tabs.append(rrb.Vertical(*views, name=sensor.capitalize()))
    tabs.append(rrb.Vertical(*[
        rrb.TimeSeriesView(name=QUALITY_TITLES[q], origin="/",
                           contents=[f"drift/quality/{q}/**"], axis_x=_whole_axis())
        for q in QUALITY], name="Quality"))
    tabs.append(rrb.TextDocumentView(name="Table", origin="drift/summary"))
    return rrb.Blueprint(rrb.Tabs(*tabs), *_panels(CALIBRATED_AT), auto_layout=False,
                         auto_views=False)


def _num(x: float, fmt: str = ".6g") -> str:
    return "–" if not np.isfinite(x) else format(x, fmt)


def _drift_markdown(drifts: list[DeviceDrift]) -> str:
    lines = ["# Drift per device", "",
             "change = last − first; per 30 d = least-squares slope; change/σ = the change over "
             "both fits' standard errors (|change/σ| > 3: the unit moved, not the fit)."]
    for d in drifts:
        dates = [iso(t)[:16] for t in d.times]
        lines += ["", f"## {d.device}", "",
                  "| parameter | unit | " + " | ".join(dates) + " | change | per 30 d | "
                  "change/σ |", "|---|---|" + "---:|" * (len(dates) + 3)]
        lines += [f"| {p.param.label} | {p.unit} | " + " | ".join(_num(v) for v in p.values)
                  + f" | {_num(p.change, '+.4g')} | {_num(p.per_30d, '+.4g')} | "
                  f"{_num(p.change_sigma, '+.1f')} |" for p in d.params]
        lines += [f"- {n}" for n in d.notes]
    return "\n".join(lines) + "\n"


# --- the fleet report ----------------------------------------------------------------------------


def save_fleet_report(rep: FleetReport, path: str | os.PathLike) -> None:
    """The fleet report: robust z of every parameter of every device, outliers in red."""
    _save(path, f"fleet report at {iso(rep.at)}", _fleet_blueprint(len(rep.spreads)),
          lambda rec: _log_fleet(rec, rep))


def _log_fleet(rec: rr.RecordingStream, rep: FleetReport) -> None:
    xs, ys, colors, labels, radii = [], [], [], [], []
    devices, params, values, zs = [], [], [], []
    n = max(len(rep.devices), 1)
    for i, s in enumerate(rep.spreads):
        flagged = set(s.outliers.tolist())
        for k, (d, v, z) in enumerate(zip(s.devices, s.values, s.z)):
            out = k in flagged  # the fleet's test decides, not a line on the z axis
            # Devices side by side within a parameter's column, in the fleet's order.
            xs.append(i + 0.6 * (rep.devices.index(d) + 0.5) / n - 0.3)
            ys.append(-float(np.clip(z, -Z_SHOWN, Z_SHOWN)))  # 2D views draw y downwards
            colors.append(BEFORE if out else GREY)
            radii.append(6.0 if out else 3.5)
            labels.append(f"{d}: z = {z:+.1f}" if out else "")
            devices.append(d)
            params.append(s.param.label)
            values.append(float(v))
            zs.append(float(z))
        rec.log(f"fleet/parameters/{s.param.sensor}/{s.param.name}", rr.AnyValues(
            unit=s.unit, devices=s.devices, values=s.values, z=s.z, median=s.median,
            mad=s.mad, z_from=s.z_from,
            outliers=[s.devices[k] for k in s.outliers] or [""]), static=True)
    if xs:
        rec.log("fleet/z/points", rr.Points2D(
            np.column_stack([xs, ys]), colors=rgba(colors), labels=labels, show_labels=True,
            radii=[rr.Radius.ui_points(r) for r in radii], draw_order=20.0),
            rr.AnyValues(device=devices, parameter=params, value=np.array(values),
                         z=np.array(zs)), static=True)
        _log_frame(rec, [_short(s.param.sensor, s.param.name) for s in rep.spreads])
    out = rep.outliers
    path = dict(zip(rep.devices, rep.paths))
    fields = {"count": len(out)}
    if out:
        fields |= {"device": [o.device for o in out],
                   "parameter": [o.spread.param.label for o in out],
                   "unit": [o.spread.unit for o in out], "value": np.array([o.value for o in out]),
                   "z": np.array([o.z for o in out]), "path": [path[o.device] for o in out]}
    rec.log("fleet/outliers", rr.AnyValues(**fields), static=True)
    rec.log("fleet/report", rr.TextDocument(_fleet_markdown(rep),
                                            media_type=rr.MediaType.MARKDOWN), static=True)


def _log_frame(rec: rr.RecordingStream, names: list[str]) -> None:
    """The zero line and the parameter names: a Spatial2DView has no axes. No limit line: the
    outliers are decided by a test on the fleet's values, not by a fixed z."""
    right = len(names) - 0.5
    rec.log("fleet/z/frame/zero", rr.LineStrips2D(
        [[[-0.5, 0.0], [right, 0.0]]], colors=rgba([GREY]), radii=rr.Radius.ui_points(0.5),
        draw_order=1.0), static=True)
    # Names on three alternating rows below the plot, so that neighbours do not overlap.
    pos = [[i, Z_SHOWN + 1.0 + 1.3 * (i % 3)] for i in range(len(names))]
    rec.log("fleet/z/frame/names", rr.Points2D(
        pos, labels=names, colors=rgba([GREY]), radii=rr.Radius.ui_points(0.5),
        show_labels=True, draw_order=2.0), static=True)


def _short(sensor: str, name: str) -> str:
    return f"{'acc' if sensor == 'accelerometer' else 'gyro'} {name}"


def _fleet_blueprint(n_params: int) -> rrb.Blueprint:
    # The whole z range and the names below it in view from the start (the default bounds
    # follow the bulk of the points and can leave the outliers out).
    bounds = rrb.VisualBounds2D(x_range=[-1.0, max(n_params, 1)],
                                y_range=[-Z_SHOWN - 1.5, Z_SHOWN + 5.0])
    z = rrb.Spatial2DView(name=f"Robust z per parameter and device, up = positive (outliers "
                               f"in red; drawn within ±{Z_SHOWN:g})",
                          origin="fleet/z", contents=["fleet/z/**"], visual_bounds=bounds)
    return rrb.Blueprint(
        rrb.Tabs(rrb.Horizontal(z, rrb.TextDocumentView(name="Report", origin="fleet/report"),
                                column_shares=[3, 2], name="Outliers"),
                 rrb.TextDocumentView(name="Report", origin="fleet/report")),
        *_panels(), auto_layout=False, auto_views=False)


def _fleet_markdown(rep: FleetReport) -> str:
    out = rep.outliers
    lines = [f"# Fleet report: {len(rep.devices)} devices at {iso(rep.at)}", "",
             "Newest calibration of each device. Robust z = 0.6745 (x − median) / MAD shows "
             "where each unit lies; the outliers are those of the generalized ESD test at "
             f"{ESD_ALPHA:.0%} per parameter (Dixon's Q with 3 or 4 units).", "",
             f"## Outliers: {len(out)}", ""]
    lines += [f"- **{o.device}**: {o.spread.param.label} = {o.value:.5g} {o.spread.unit} "
              f"(median {o.spread.median:.5g}, z = {o.z:+.1f})" for o in out] or ["none"]
    lines += ["", "## Parameters", "",
              "| parameter | outliers | unit | n | median | MAD | min | max | max abs z |",
              "|---|---|---|---:|---:|---:|---:|---:|---:|"]
    for s in rep.spreads:
        flagged = ", ".join(f"**{s.devices[i]}**" for i in s.outliers) or "–"
        lines.append(f"| {s.param.label} | {flagged} | {s.unit} | {len(s.devices)} | "
                     f"{s.median:.5g} | {s.mad:.3g} | {s.values.min():.5g} | "
                     f"{s.values.max():.5g} | {np.abs(s.z).max():.1f} |")
    lines += ["", "## Devices", "", "| device | calibrated at | file |", "|---|---|---|"]
    lines += [f"| {d} | {iso(t)} | {p} |" for d, t, p in zip(rep.devices, rep.calibrated_at,
                                                          rep.paths)]
    lines += [f"- {n}" for n in rep.notes]
    return "\n".join(lines) + "\n"
