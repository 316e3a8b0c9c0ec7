"""The guide to the recording (Overview tab): :attr:`imucal.result.Result.guide` laid out.

A sphere of the poses reached (each still block's gravity direction, the axis that was up),
the directions no pose comes near, and the poses to record next; each pose's hold at its
middle against the shortest hold that counts and the hold advised; each turn's peak rate and
gravity tilt at its middle against their limits. The limits are lines of two rows (the
session's first and last sample), so every plot draws on the timeline ``time`` the layout
opens on. Every number is the core's (:mod:`imucal.stages.guide`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from imucal.stages.accel_cv import axis_words

from . import paths as P
from .columns import BEFORE, GREY, MEASURED, XYZ, rgba, send_scalars, style_lines, style_points

if TYPE_CHECKING:
    from imucal.result import Result
    from imucal.stages.guide import Guide

NEXT = 0xF28E2BFF  # orange: what to record next
MISSING = 0xD62728FF
ANGLE = 0x4E79A7FF


def log_guide(result: Result, rec: rr.RecordingStream, rows: dict[str, int]) -> None:
    g = result.guide
    if g is None:
        return
    _log_sphere(g, rec)
    t = result.session.t_acc
    span = [float(t[0]), float(t[-1])]
    h = g.holds
    mid = result.block_middles
    # The guide's one minimum and one advice (imucal.stages.guide): the hold that counts, the
    # hold advised; each pose's hold is its block with the detector window's edges.
    rows[P.GUIDE_HOLD] = send_scalars(rec, P.GUIDE_HOLD, mid, h.hold_s)
    style_points(rec, P.GUIDE_HOLD, ["pose hold (s)"], [MEASURED])
    _flagged(rec, P.GUIDE_HOLD_NEAR_MIN, mid, h.hold_s, h.near_min,
             f"held under {h.near_s:.2g} s", rows)
    _line(rec, P.GUIDE_HOLD_MIN, span, h.count_s,
          f"a hold counts from {h.count_s:.2g} s ({h.min_source})", BEFORE, rows)
    _line(rec, P.GUIDE_HOLD_WARN, span, h.recommended_s, f"advised {h.recommended_s:g} s",
          GREY, rows)

    tg = g.turns
    if len(tg.peak_rate):
        tm = tg.times.mean(axis=1)
        rows[P.GUIDE_TURN_RATE] = send_scalars(rec, P.GUIDE_TURN_RATE, tm, tg.peak_rate)
        style_points(rec, P.GUIDE_TURN_RATE, ["turn peak |w| (rad/s)"], [MEASURED])
        _flagged(rec, P.GUIDE_TURN_FAST, tm, tg.peak_rate, tg.fast, "over the limit", rows)
        _line(rec, P.GUIDE_TURN_LIMIT, span, tg.rate_limit,
              f"limit {tg.rate_limit:.3g} rad/s", BEFORE, rows)
        rows[P.GUIDE_TURN_TILT] = send_scalars(rec, P.GUIDE_TURN_TILT, tm, tg.tilt_deg)
        style_points(rec, P.GUIDE_TURN_TILT, ["gravity tilt (deg)"], [MEASURED])
        rows[P.GUIDE_TURN_ANGLE] = send_scalars(rec, P.GUIDE_TURN_ANGLE, tm, tg.angle_deg)
        style_points(rec, P.GUIDE_TURN_ANGLE, ["rotation angle (deg)"], [ANGLE], size=5.0,
                     marker="cross")
        _line(rec, P.GUIDE_TURN_MIN_TILT, span, tg.min_tilt_deg,
              f"minimum tilt {tg.min_tilt_deg:g} deg", BEFORE, rows)
    _log_info(g, rec)


def _flagged(rec: rr.RecordingStream, path: str, t: np.ndarray, v: np.ndarray,
             flag: np.ndarray, name: str, rows: dict[str, int]) -> None:
    """The flagged rows again, larger and red, over the series (nothing when none is)."""
    if flag.any():
        rows[path] = send_scalars(rec, path, t[flag], v[flag])
        style_points(rec, path, [name], [MISSING], size=6.0)


def _line(rec: rr.RecordingStream, path: str, span: list[float], value: float, name: str,
          color: int, rows: dict[str, int]) -> None:
    rows[path] = send_scalars(rec, path, span, np.full(2, value))
    style_lines(rec, path, [name], [color], width=1.5)


def _circle(normal_axis: int, n: int = 96) -> np.ndarray:
    a = np.linspace(0, 2 * np.pi, n)
    c = np.zeros((n, 3))
    i, j = [k for k in range(3) if k != normal_axis]
    c[:, i], c[:, j] = np.cos(a), np.sin(a)
    return c


def _log_sphere(g: Guide, rec: rr.RecordingStream) -> None:
    p = g.poses
    rec.log(P.GUIDE_SPHERE, rr.LineStrips3D([_circle(k) for k in range(3)],
                                            colors=rgba([GREY] * 3), radii=0.004), static=True)
    rec.log(P.GUIDE_AXES, rr.Arrows3D(vectors=np.eye(3) * 1.35, colors=rgba(XYZ),
                                      labels=["x", "y", "z"], radii=0.008), static=True)
    rec.log(P.GUIDE_POSES, rr.Points3D(p.gravity, colors=rgba([MEASURED] * len(p.gravity)),
                                       radii=0.045), static=True)
    rec.log(P.GUIDE_MISSING, rr.Points3D(p.missing, colors=rgba([MISSING] * len(p.missing)),
                                         radii=0.018), static=True)
    labels = [axis_words(v) for v in p.suggested]  # short: six of them may crowd the sphere
    rec.log(P.GUIDE_NEXT, rr.Arrows3D(vectors=p.suggested * 1.15,
                                      colors=rgba([NEXT] * len(p.suggested)), labels=labels,
                                      radii=0.02), static=True)


def _log_info(g: Guide, rec: rr.RecordingStream) -> None:
    t = g.turns
    rec.log(P.GUIDE_INFO, rr.AnyValues(
        orientations=int(g.poses.orientations), coverage=float(g.poses.coverage),
        min_s=float(g.holds.min_s), min_len=int(g.holds.min_len),
        min_hold_s=float(g.holds.count_s), advised_hold_s=float(g.holds.recommended_s),
        min_source=g.holds.min_source, short_holds=int(g.holds.short_holds),
        short_holds_at_s=np.asarray(g.holds.short_at_s, dtype=float),
        rate_limit=float(t.rate_limit), limit_source=t.limit_source,
        full_scale=float("nan") if t.full_scale is None else float(t.full_scale),
        full_scale_source=t.full_scale_source, min_tilt_deg=float(t.min_tilt_deg),
        strong=np.array(list(g.strong) or [""], dtype=str),
        weak=np.array(list(g.weak) or [""], dtype=str),
        record_next=np.array(list(g.record_next) or [""], dtype=str)), static=True)


def _whole_axis() -> rrb.TimeAxis:
    return rrb.TimeAxis(view_range=rrb.TimeRange(start=rrb.TimeRangeBoundary.infinite(),
                                                 end=rrb.TimeRangeBoundary.infinite()))


def _ts(name: str, *contents: str, top: float | None = None) -> rrb.TimeSeriesView:
    """No legend: it would cover the points; the title names the colours and the limits.
    ``top``: the y axis from 0 to it (a small plot's own range can leave it one tick, or
    none: "Still block duration" on a session whose holds all lie near the minimum)."""
    axis_y = None if top is None else rrb.ScalarAxis(range=(0.0, top))
    return rrb.TimeSeriesView(name=name, origin="/", contents=list(contents),
                              axis_x=_whole_axis(), axis_y=axis_y,
                              plot_legend=rrb.PlotLegend(visible=False))


def _top(*values) -> float | None:
    """A y axis's top: 12 % over the largest finite value (None when there is none)."""
    v = np.concatenate([np.ravel(np.asarray(x, float)) for x in values])
    v = v[np.isfinite(v)]
    return float(v.max()) * 1.12 if len(v) and v.max() > 0 else None


def guide_views(result: Result | None = None) -> list[rrb.View]:
    """The guide's views for the Overview tab: the sphere, the holds, and (with a gyroscope)
    the turns' peak rate and tilt. Titles carry the limits' values where ``result`` is
    given."""
    g = None if result is None else result.guide
    gyro = g is None or len(g.turns.peak_rate) > 0
    hold_min = ("" if g is None else
                f" {g.holds.count_s:.2g} s, grey: advised {g.holds.recommended_s:g} s")
    rate = "" if g is None else f" {g.turns.rate_limit:.3g}"
    tilt = "" if g is None else f" {g.turns.min_tilt_deg:g}"
    views: list[rrb.View] = [
        rrb.Spatial3DView(
            name="Poses (axis up): reached green, missing red, next orange",
            origin=P.GUIDE, contents=[f"{P.GUIDE}/**"],
            line_grid=rrb.LineGrid3D(visible=False),
            eye_controls=rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital,
                                           position=[1.65, -2.0, 1.35], look_target=[0, 0, 0],
                                           eye_up=[0, 0, 1])),
        _ts(f"Pose holds (s); red: counts from{hold_min}",
            P.GUIDE_HOLD, P.GUIDE_HOLD_NEAR_MIN, P.GUIDE_HOLD_MIN, P.GUIDE_HOLD_WARN,
            top=None if g is None else _top(g.holds.hold_s, g.holds.recommended_s))]
    if gyro:
        t = None if g is None else g.turns
        views += [_ts(f"Turns: peak rate (rad/s); red line: limit{rate}", P.GUIDE_TURN_RATE,
                      P.GUIDE_TURN_FAST, P.GUIDE_TURN_LIMIT,
                      top=None if t is None else _top(t.peak_rate, t.rate_limit)),
                  _ts(f"Turns: gravity tilt (deg) green, rotation blue; red: min{tilt}",
                      P.GUIDE_TURN_TILT, P.GUIDE_TURN_ANGLE, P.GUIDE_TURN_MIN_TILT,
                      top=None if t is None else _top(t.tilt_deg, t.angle_deg,
                                                      t.min_tilt_deg))]
    return views


def guide_column(result: Result | None = None) -> rrb.Vertical:
    """:func:`guide_views` stacked, the sphere taller than the plots."""
    views = guide_views(result)
    # The sphere reads well small; the plots need height for their y ticks (the time plots
    # label every 1, 10 or 100 units, whichever is at least ~25 px apart: the holds, up to
    # ~9 s on the Ferraris session, need ~230 px to show theirs).
    return rrb.Vertical(*views, row_shares=[1.0, 1.25] + [1.0] * (len(views) - 2))
