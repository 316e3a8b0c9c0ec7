"""The L-curve tab's entities, all 2D plots (:mod:`viewer.plot2d`): each fit's L-curve with
its corner, and what each lambda of the whole-session sweep gives (static norm error and the
9 accelerometer parameters against lambda), read from :class:`~imucal.stages.accel.LCurve`
and :class:`~imucal.stages.accel.LambdaSweep` (method.md M3)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import rerun as rr

from imucal.models import ACC_PARAM_NAMES

from . import paths as P
from .columns import CALIBRATED, CORNER, RAW, SEGMENT_COLORS, XYZ, log10_axis
from .layout import LCURVE_BOX, SWEEP_BOX, Box
from .plot2d import (
    LABEL_DROP,
    LABEL_PX,
    TEXT,
    Axis,
    Mark,
    Series,
    label_width,
    linear_axis,
    log_axis,
    log_plot,
    text,
    to_scene,
)

if TYPE_CHECKING:
    from imucal.result import Result


def log_lcurves(result: Result, rec: rr.RecordingStream, rows: dict[str, int]) -> None:
    whole = result.whole
    lc = whole.lcurve
    if lc is None:
        return
    curves = [(P.LCURVE_POINTS, lc, CALIBRATED, "whole session")]
    if len(result.segments) > 1:
        curves += [(P.lcurve_segment(s.number), s.acc.lcurve,
                    SEGMENT_COLORS[s.number % len(SEGMENT_COLORS)], f"segment {s.number}")
                   for s in result.segments if s.acc.lcurve is not None]
    _log_lcurve_plot(rec, curves)
    if whole.sweep is not None:
        _log_sweep(result, rec)


# --- the L-curve -------------------------------------------------------------------------------


def _log_lcurve_plot(rec: rr.RecordingStream, curves: list, root: str = P.LCURVE,
                     box: Box = LCURVE_BOX, eta: str = "|θ − θ0|") -> None:
    """rho against eta, both log10 (y up: eta grows upwards), each point labelled with its
    lambda where the label has room, each corner in red with its own label (placed first);
    ``root`` the plot's path (the magnetometer's curve, M8r, has its own), ``eta`` what the
    solution norm is of."""
    xy = [np.column_stack([log10_axis(lc.residual_norm), log10_axis(lc.solution_norm)])
          for _, lc, _, _ in curves]
    allxy = np.vstack(xy)
    xa, ya = log_axis(allxy[:, 0]), log_axis(allxy[:, 1])
    taken: list[tuple[float, float, float, float]] = []  # label boxes already placed
    corners = []
    for (path, lc, _, name), pts in zip(curves, xy):
        c = lc.corner
        if 0 <= c < len(lc.lambdas) and np.all(np.isfinite(pts[c])):
            # Well posed, the "corner" is only where the prior starts to bias the fit.
            what = "chosen λ = {:.3g} (no corner)" if lc.well_posed else "corner λ = {:.3g}"
            label = ("" if len(curves) == 1 else f"{name}: ") + what.format(lc.lambdas[c])
            taken.append(_label_box(to_scene(box, xa, ya, pts[c:c + 1])[0], label, 7.0))
            corners.append(Series(
                _corner_name(path, root),
                "", CORNER, pts[c:c + 1, 0], pts[c:c + 1, 1], line=False, size=7.0,
                labels=[label], values={"lambda": float(lc.lambdas[c]), "index": int(c),
                                        "residual_norm": float(lc.residual_norm[c]),
                                        "solution_norm": float(lc.solution_norm[c])}))
    series = []
    for (path, lc, color, name), pts in zip(curves, xy):
        labels = _thin(to_scene(box, xa, ya, pts), [f"λ={la:.2g}" for la in lc.lambdas],
                       lc.corner, taken)
        series.append(Series(_rel(path, root), name, color, pts[:, 0], pts[:, 1],
                             size=3.0, labels=labels,
                             values={"lambda": np.asarray(lc.lambdas, float),
                                     "residual_norm": np.asarray(lc.residual_norm, float),
                                     "solution_norm": np.asarray(lc.solution_norm, float)}))
    log_plot(rec, root, box, xa, ya, series + corners, legend=len(curves) > 1)
    title_x = "residual norm ρ = |r_data|  (log scale) →"
    title_y = f"↑ solution norm η = {eta}  (log scale)"
    text(rec, f"{root}/frame/titles",
         [[box.width / 2, box.height + 40], [label_width(title_y) / 2 - box.left + 6,
                                             -box.top + LABEL_PX / 2]],
         [title_x, title_y], [TEXT])


def _corner_name(path: str, root: str = P.LCURVE) -> str:
    """The corner's series: ``corner`` for the whole session (``<root>/points``),
    ``segment_<i>_corner``."""
    return "corner" if path == P.series(root, "points") else _rel(path, root) + "_corner"


def _rel(path: str, root: str = P.LCURVE) -> str:
    """A series' path below the plot (what :class:`Series` takes)."""
    return path.removeprefix(root + "/")


def _label_box(centre: np.ndarray, label: str, radius: float
               ) -> tuple[float, float, float, float]:
    """Where a point's label is drawn (x0, y0, x1, y1, scene units): centred below it."""
    x, y = float(centre[0]), float(centre[1]) + LABEL_DROP + max(radius - 3.0, 0.0)
    half = label_width(label) / 2
    return (x - half, y - LABEL_PX / 2, x + half, y + LABEL_PX / 2)


def _overlaps(a: tuple, b: tuple, gap: float = 2.0) -> bool:
    return not (a[2] + gap <= b[0] or b[2] + gap <= a[0] or a[3] + gap <= b[1]
                or b[3] + gap <= a[1])


def _thin(scene: np.ndarray, labels: list[str], skip: int, taken: list) -> list[str]:
    """The labels that fit: from the large-lambda end (where points spread out) each label is
    kept when its box overlaps no label already placed (``taken``, which it extends; the
    corner's is placed first). ``skip`` (the corner) is never labelled here."""
    out = [""] * len(labels)
    for i in range(len(labels) - 1, -1, -1):
        if i == skip or not np.all(np.isfinite(scene[i])):
            continue
        b = _label_box(scene[i], labels[i], 3.0)
        if not any(_overlaps(b, t) for t in taken):
            out[i] = labels[i]
            taken.append(b)
    return out


# --- the sweep ---------------------------------------------------------------------------------


def _log_sweep(result: Result, rec: rr.RecordingStream) -> None:
    """What each lambda would have given, against log10 lambda, the chosen one marked."""
    lc, sweep = result.whole.lcurve, result.whole.sweep
    lam = np.asarray(lc.lambdas, float)
    x = log10_axis(lam)
    xa = log_axis(x)
    c = lc.corner if 0 <= lc.corner < len(lam) else -1
    chosen = "chosen λ = {:.3g} (no corner)" if lc.well_posed else "corner λ = {:.3g}"
    mark = [Mark(float(x[c]), chosen.format(lam[c]), CORNER)] if c >= 0 else []
    rms, worst = sweep.static_norm_rms_mg, sweep.static_norm_max_mg
    y = {"rms": log10_axis(rms), "max": log10_axis(worst)}
    static = [Series("rms", "RMS", CALIBRATED, x, y["rms"], values={"lambda": lam, "mg": rms}),
              Series("max", "max |.|", RAW, x, y["max"], values={"lambda": lam, "mg": worst})]
    if c >= 0:
        static.append(Series("chosen", "", CORNER, x[c:c + 1], y["rms"][c:c + 1], line=False,
                             size=5.0, values={"lambda": float(lam[c]), "mg": float(rms[c])}))
    log_plot(rec, P.LAMBDA_STATIC, SWEEP_BOX, xa, log_axis(np.concatenate(list(y.values()))),
             static, mark)
    unit = result.session.acc_unit
    params = sweep.params
    for plot, cols, suffix in ((P.LAMBDA_MISALIGNMENT, slice(0, 3), " (rad)"),
                               (P.LAMBDA_SCALE, slice(3, 6), ""),
                               (P.LAMBDA_BIAS, slice(6, 9), f" ({unit})")):
        names = ACC_PARAM_NAMES[cols]
        _log_params(rec, plot, xa, x, params[:, cols], names, suffix,
                    {"lambda": lam}, [Mark(m.x, "", m.color) for m in mark])


def _log_params(rec: rr.RecordingStream, plot: str, xa: Axis, x: np.ndarray, v: np.ndarray,
                names: tuple[str, ...], suffix: str, values: dict, marks: list[Mark]) -> None:
    series = [Series(n, f"{n}{suffix}", col, x, v[:, i], values=values, size=2.0)
              for i, (n, col) in enumerate(zip(names, XYZ))]
    log_plot(rec, plot, SWEEP_BOX, xa, linear_axis(v), series, marks)
