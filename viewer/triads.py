"""The Triads tab's entities (issue 24, item 4; method.md §11): a session with more than one
accelerometer triad, each calibrated on its own and put in the reference's frame
(``Result.triads``).

- per other triad, each shared still block's gravity in both triads compared, in mg, at the
  block's middle: before calibration (raw means in each triad's nominal frame,
  ``TriadAgreement.before_mg``), calibrated but each in its own frame (``unrotated_mg``: what
  the rotation between them is worth), calibrated and rotated (M12) in sample (``after_mg``)
  and with the block held out (``held_out_mg``, the figure the summary reports);
- the rotation to the reference (M13) and the gyroscope's from the turns (M14), each with its
  standard error about the reference's axes, as AnyValues;
- the triads' figures side by side in a markdown table: the reference and every other triad,
  each its own calibration's figures, then the rotation and the agreement.

Nothing is logged for a session of one triad.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from . import paths as P
from .columns import AFTER, BEFORE, CALIBRATED, nan_if_none, send_scalars, style_points

if TYPE_CHECKING:
    from imucal.result import Result, Triad
    from imucal.stages.triads import RotationFit

OWN_FRAME = 0xEDC948FF  # yellow: apart from the red "before" and the blue "after"
# (what, legend name, colour, marker) of each per-block series, in drawing order
SERIES = (("before_mg", "before calibration", BEFORE, "circle"),
          ("unrotated_mg", "calibrated, own frame", OWN_FRAME, "square"),
          ("after_mg", "calibrated and rotated", CALIBRATED, "diamond"),
          ("held_out_mg", "rotated, block held out", AFTER, "circle"))


def triad_number(k: int) -> int:
    """The ``k``-th other triad as the tab counts it: from 2, the reference being 1."""
    return k + 2


def rotvec_deg(R: np.ndarray) -> np.ndarray:
    """(3,) the rotation vector of ``R``, deg: its angle about each of the reference's axes."""
    from scipy.spatial.transform import Rotation

    return np.degrees(Rotation.from_matrix(np.asarray(R, float)).as_rotvec())


def log_triads(result: Result, rec: rr.RecordingStream, rows: dict[str, int]) -> None:
    if not result.triads:
        return
    mid = result.block_middles
    for k, tri in enumerate(result.triads):
        i = triad_number(k)
        a = tri.agreement
        if a is not None:
            t = mid[a.used]
            for what, name, color, marker in SERIES:
                v = getattr(a, what)
                if v is None:
                    continue
                path = P.triad(i, what)
                rows[path] = send_scalars(rec, path, t, v)
                style_points(rec, path, [f"{tri.name}: {name} (mg)"], [color], size=3.0,
                             marker=marker)
        rec.log(P.triad(i, "info"), rr.AnyValues(**triad_values(tri)), static=True)
    rec.log(P.TRIADS_NOTE, rr.TextDocument(triads_note(result), media_type="text/markdown"),
            static=True)


def _rotation_values(prefix: str, fit: RotationFit | None) -> dict:
    if fit is None:
        nan3 = np.full(3, np.nan)
        return {f"{prefix}R": np.full(9, np.nan), f"{prefix}rotvec_deg": nan3,
                f"{prefix}std_deg": nan3, f"{prefix}angle_deg": np.nan,
                f"{prefix}std_total_deg": np.nan}
    rv = rotvec_deg(fit.R)
    return {f"{prefix}R": fit.R.ravel(), f"{prefix}rotvec_deg": rv,
            f"{prefix}std_deg": fit.std_deg, f"{prefix}angle_deg": float(np.linalg.norm(rv)),
            f"{prefix}std_total_deg": fit.std_total_deg}


def triad_values(tri: Triad) -> dict:
    """A triad's figures as plain values (NaN where not estimated)."""
    a, g = tri.agreement, tri.gyro_agreement
    out = {"name": tri.name, "gyro": tri.gyro or "", "calibrated": tri.result is not None,
           "blocks": 0 if a is None else a.blocks,
           "held_out_rms_mg": np.nan if a is None else a.held_out_rms_mg,
           "before_rms_mg": np.nan if a is None else a.before_rms_mg,
           "clock_offset_s": nan_if_none(tri.clock_offset_s),
           "turns": 0 if g is None else g.turns,
           "gyro_residual_rms_deg": np.nan if g is None else g.residual_rms_deg,
           "gyro_vs_accel_deg": np.nan if g is None else nan_if_none(g.accel_difference_deg),
           "said": list(tri.said) or [""]}
    out |= _rotation_values("", None if a is None else a.rotation)
    out |= _rotation_values("gyro_", None if g is None else g.rotation)
    return out


def _fmt(x: float | None, spec: str, unit: str = "") -> str:
    if x is None or not np.isfinite(x):
        return "–"
    return f"{x:{spec}}{unit}"


def _own(res: Result | None) -> list[str]:
    """A run's own figures: verdict, still blocks, still-norm and rotation error after."""
    if res is None:
        return ["not calibrated", "–", "–", "–"]
    q = res.quality
    gravity = q.gravity_angle_rms_deg
    return [res.verdict.level if res.verdict is not None else "–", str(len(res.block_times)),
            _fmt(q.static_norm_rms_mg.after, ".3g", " mg"),
            _fmt(None if gravity is None else gravity.after, ".3g", " deg")]


def triads_note(result: Result) -> str:
    """The triads' figures side by side (a column each, the reference first), then what was
    said about each."""
    head = ["", f"reference ({result.session.chosen[0] if result.session.chosen else 'acc'})"]
    head += [f"{triad_number(k)}: {t.name}" for k, t in enumerate(result.triads)]
    rows: list[list[str]] = [["own verdict"], ["still blocks"], ["still-norm RMS after"],
                             ["rotation error RMS after"]]
    for col in [_own(result)] + [_own(t.result) for t in result.triads]:
        for r, v in zip(rows, col):
            r.append(v)
    more = [["turned from the reference", "–"], ["about x, y, z (± 1σ)", "–"],
            ["shared still blocks", "–"], ["gravity difference before", "–"],
            ["gravity difference held out", "–"], ["gyroscope turned (turns)", "–"],
            ["gyroscope vs accelerometer", "–"], ["clock offset", "–"]]
    for tri in result.triads:
        v = triad_values(tri)
        about = "–" if not np.isfinite(v["angle_deg"]) else ", ".join(
            f"{r:+.3f} ± {s:.3f}" for r, s in zip(v["rotvec_deg"], v["std_deg"])) + " deg"
        cells = [_fmt(v["angle_deg"], ".3f", f" ± {_fmt(v['std_total_deg'], '.3f')} deg"),
                 about, str(v["blocks"]), _fmt(v["before_rms_mg"], ".3g", " mg RMS"),
                 _fmt(v["held_out_rms_mg"], ".3g", " mg RMS"),
                 _fmt(v["gyro_angle_deg"], ".3f", f" ± {_fmt(v['gyro_std_total_deg'], '.3f')}"
                      f" deg ({v['turns']})"),
                 _fmt(v["gyro_vs_accel_deg"], ".3f", " deg"),
                 _fmt(v["clock_offset_s"], "+.4f", " s")]
        for r, c in zip(more, cells):
            r.append(c)
    table = [head, ["---"] * len(head), *rows, *more]
    lines = ["| " + " | ".join(r) + " |" for r in table]
    said = [f"- {s}" for t in result.triads for s in t.said]
    return "\n".join(["**Triads** (method.md §11): each calibrated on its own, then turned into "
                      "the reference's frame", "", *lines] + (["", *said] if said else []))


def triads_titles(result: Result, k: int) -> tuple[str, str]:
    """The ``k``-th other triad's two per-block plots' titles (every stage; after alone):
    its name and agreement."""
    tri = result.triads[k]
    a = tri.agreement
    if a is None:
        return (f"{tri.name}: no rotation estimated (too few shared still blocks)",
                f"{tri.name}: calibrated and rotated")
    return (f"{tri.name} vs reference, |Δ gravity| per block (mg): before red "
            f"({a.before_rms_mg:.3g} RMS), calibrated in its own frame yellow, rotated blue",
            f"{tri.name}, calibrated and rotated (mg): in sample ◆, block held out ● "
            f"({a.held_out_rms_mg:.3g} RMS)")


def triads_tab(result: Result, time_axis, lanes) -> rrb.Horizontal:
    """Each other triad's per-block gravity difference over the still blocks' lane, the
    figures side by side beside them. ``time_axis`` and ``lanes`` are the layout's."""
    views = []
    for k in range(len(result.triads)):
        i = triad_number(k)
        every, after = triads_titles(result, k)
        views.append(rrb.Vertical(*[rrb.TimeSeriesView(
            name=name, origin="/", contents=[P.triad(i, what) for what in whats],
            axis_x=time_axis(), plot_legend=rrb.PlotLegend(visible=False))
            for name, whats in ((every, [w for w, *_ in SERIES]),
                                (after, ["after_mg", "held_out_mg"]))]))
    n = len(views)
    return rrb.Horizontal(
        rrb.Vertical(*views, lanes(), row_shares=[1.0] * n + [0.15 * n + 0.05]),
        rrb.TextDocumentView(name="Triads", origin=P.TRIADS_NOTE),
        column_shares=[3, 2], name="Triads")
