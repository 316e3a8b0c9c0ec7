"""The L-curve tab's entities: each fit's L-curve as a 2D plot (static), and the whole-session
sweep on the ``lambda`` timeline, read from :class:`~imucal.stages.accel.LambdaSweep`."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import rerun as rr

from imucal.models import ACC_PARAM_NAMES

from . import paths as P
from .columns import (
    CALIBRATED,
    CORNER,
    GREY,
    MEASURED,
    PREVIOUS,
    RAW,
    SEGMENT_COLORS,
    XYZ,
    log10_axis,
    rgba,
    send_scalars,
    style_lines,
    style_points,
)

if TYPE_CHECKING:
    from imucal.result import Result
    from imucal.stages.accel import LCurve


def log_lcurves(result: Result, rec: rr.RecordingStream, rows: dict[str, int]) -> None:
    whole = result.whole
    lc = whole.lcurve
    if lc is None:
        return
    several = len(result.segments) > 1
    pts = [_log_one_lcurve(rec, P.LCURVE, lc, CALIBRATED, "whole session" if several else None)]
    if several:
        for seg in result.segments:
            if seg.acc.lcurve is not None:
                color = SEGMENT_COLORS[(seg.index + 1) % len(SEGMENT_COLORS)]
                pts.append(_log_one_lcurve(rec, P.lcurve_segment(seg.index), seg.acc.lcurve,
                                           color, f"segment {seg.index}"))
    allpts = np.vstack(pts)
    if len(allpts):
        _log_frame(rec, allpts)
    if whole.sweep is not None:
        _log_sweep(result, rec, rows)


def _log_sweep(result: Result, rec: rr.RecordingStream, rows: dict[str, int]) -> None:
    """What each lambda would have given, on the ``lambda`` timeline."""
    lc, sweep = result.whole.lcurve, result.whole.sweep
    idx = np.arange(len(lc.lambdas))
    rms = sweep.static_norm_rms_mg
    params = sweep.params
    series = {
        P.LAMBDA_LOG10: (log10_axis(lc.lambdas), ["log10 λ"], [PREVIOUS]),
        P.LAMBDA_STATIC_RMS: (rms, ["static norm error RMS (mg)"], [CALIBRATED]),
        P.LAMBDA_STATIC_MAX: (sweep.static_norm_max_mg, ["static norm error max |.| (mg)"],
                              [RAW]),
        P.LAMBDA_RESIDUAL: (log10_axis(lc.residual_norm), ["log10 ρ (residual norm)"], [RAW]),
        P.LAMBDA_SOLUTION: (log10_axis(lc.solution_norm), ["log10 η (solution norm)"],
                            [MEASURED]),
        P.LAMBDA_MISALIGNMENT: (params[:, 0:3], [f"{n} (rad)" for n in ACC_PARAM_NAMES[0:3]],
                                XYZ),
        P.LAMBDA_SCALE: (params[:, 3:6], list(ACC_PARAM_NAMES[3:6]), XYZ),
        P.LAMBDA_BIAS: (params[:, 6:9], [f"{n} ({result.session.acc_unit})"
                                         for n in ACC_PARAM_NAMES[6:9]], XYZ),
    }
    for path, (v, names, colors) in series.items():
        rows[path] = send_scalars(rec, path, idx, v, timeline=P.LAMBDA)
        style_lines(rec, path, names, colors)
    c = lc.corner
    if 0 <= c < len(idx):
        rows[P.LAMBDA_CHOSEN] = send_scalars(rec, P.LAMBDA_CHOSEN, idx[c:c + 1], rms[c:c + 1],
                                             timeline=P.LAMBDA)
        style_points(rec, P.LAMBDA_CHOSEN, [f"chosen λ = {lc.lambdas[c]:.3g}"], [CORNER],
                     size=8.0, marker="diamond")


# --- the 2D plot: positions, labels and axes are drawing, not results ------------------------


def _lcurve_xy(lc: LCurve) -> np.ndarray:
    """L-curve points in the 2D view: (log10 rho, -log10 eta), y negated to draw eta upwards."""
    return np.column_stack([log10_axis(lc.residual_norm), -log10_axis(lc.solution_norm)])


def _thin_labels(xy: np.ndarray, labels: list[str], keep: int, min_dist: float) -> list[str]:
    """Blank the labels of points closer than ``min_dist`` to a labelled one (small lambdas
    pile up at one end of the curve), always keeping the label at index ``keep``."""
    out = [""] * len(labels)
    shown: list[np.ndarray] = [xy[keep]] if 0 <= keep < len(xy) else []
    for i in range(len(xy) - 1, -1, -1):  # from the large-lambda end, where points spread
        if i == keep:
            continue
        if all(np.hypot(*(xy[i] - p)) >= min_dist for p in shown):
            out[i] = labels[i]
            shown.append(xy[i])
    return out


def _log_one_lcurve(rec: rr.RecordingStream, base: str, lc: LCurve, color: int,
                    name: str | None) -> np.ndarray:
    xy = _lcurve_xy(lc)
    ok = np.all(np.isfinite(xy), axis=1)
    lams = np.asarray(lc.lambdas, float)
    corner = lc.corner if 0 <= lc.corner < len(lams) and ok[lc.corner] else -1
    pts, lam_ok = xy[ok], lams[ok]
    keep = int(np.count_nonzero(ok[:corner])) if corner >= 0 else -1
    span = float(np.ptp(pts, axis=0).max()) if len(pts) else 0.0
    labels = _thin_labels(pts, [f"λ={la:.2g}" for la in lam_ok], keep, 0.06 * span)
    if keep >= 0:
        labels[keep] = ""  # the corner has its own, larger label
    rec.log(f"{base}/points",
            rr.Points2D(pts, labels=labels, colors=rgba([color]),
                        radii=rr.Radius.ui_points(3.0), show_labels=True, draw_order=20.0),
            rr.AnyValues(**{"lambda": lam_ok}), static=True)
    rec.log(f"{base}/line", rr.LineStrips2D([pts], colors=rgba([color]),
                                            labels=None if name is None else [name],
                                            radii=rr.Radius.ui_points(1.5), draw_order=10.0),
            static=True)
    if corner >= 0:
        c = corner
        prefix = "" if name is None else f"{name}: "
        rec.log(f"{base}/corner",
                rr.Points2D(xy[c:c + 1], labels=[f"{prefix}corner λ = {lams[c]:.3g}"],
                            colors=rgba([CORNER]), radii=rr.Radius.ui_points(7.0),
                            show_labels=True, draw_order=30.0),
                rr.AnyValues(**{"lambda": float(lams[c]), "index": int(c),
                                "residual_norm": float(lc.residual_norm[c]),
                                "solution_norm": float(lc.solution_norm[c])}),
                static=True)
    return pts


def _ticks(lo: float, hi: float) -> np.ndarray:
    for step in (1.0, 0.5, 0.25, 0.1, 0.05):
        ticks = np.arange(np.ceil(lo / step) * step, hi + 1e-9, step)
        if len(ticks) >= 3:
            return ticks
    return np.array([lo, hi])


def _log_frame(rec: rr.RecordingStream, xy: np.ndarray) -> None:
    """Axes with decade ticks: a Spatial2DView has none of its own."""
    x0, x1 = float(xy[:, 0].min()), float(xy[:, 0].max())
    y0, y1 = float(xy[:, 1].min()), float(xy[:, 1].max())
    span = max(x1 - x0, y1 - y0, 0.2)
    pad = 0.08 * span
    left, right, top, bottom = x0 - pad, x1 + pad, y0 - pad, y1 + pad
    xt = _ticks(left, right)
    yt = _ticks(-bottom, -top)  # log10 eta values
    strips = [[[left, bottom], [right, bottom]], [[left, bottom], [left, top]]]
    tick = 0.015 * span
    strips += [[[x, bottom], [x, bottom + tick]] for x in xt]
    strips += [[[left, -y], [left - tick, -y]] for y in yt]
    rec.log(f"{P.LCURVE_FRAME}/axes", rr.LineStrips2D(strips, colors=rgba([GREY]),
                                                      radii=rr.Radius.ui_points(1.0),
                                                      draw_order=1.0), static=True)
    pos = [[x, bottom + 3 * tick] for x in xt] + [[left - 3 * tick, -y] for y in yt]
    lab = [f"{10**x:.2g}" for x in xt] + [f"{10**y:.2g}" for y in yt]
    pos += [[(left + right) / 2, bottom + 7 * tick], [left, top - 3 * tick]]
    lab += ["residual norm ρ = |r_data|  (log scale) →",
            "↑ solution norm η = |θ − θ0|  (log scale)"]
    rec.log(f"{P.LCURVE_FRAME}/labels", rr.Points2D(pos, labels=lab, colors=rgba([GREY]),
                                                    radii=rr.Radius.ui_points(0.5),
                                                    show_labels=True, draw_order=2.0),
            static=True)
