"""The Magnetometer tab's entities (issue 23, item 5): a calibrated magnetometer's field (M8,
:class:`imucal.stages.mag.MagFit`), raw and calibrated, with what the fit found.

- the raw samples with the fitted ellipsoid ``b + F M^-1 u`` (``MagFit.ellipsoid``) over
  circles of unit directions ``u``, in the raw unit and the magnetometer's own frame;
- the same samples calibrated (``MagFit.apply``: the accelerometer's frame when ``R_am`` was
  fitted) with the sphere of radius ``F`` they should lie on;
- ``|m| / F - 1`` over time in % (``MagFit.norm_error``), the samples the fit used apart from
  those it left out (``MagFit.used``), with a lane of ``MagFit.disturbances``;
- each still block's dip (``block_dip_deg`` at its middle, ``block_times``) apart from the
  blocks left out (``block_used``), with the fitted dip as a line;
- the quality figures and the coverage (``MagQuality``) as AnyValues and a markdown note;
- the L-curve of the shape's Tikhonov term (``MagFit.lcurve``, M8r) with its corner, a small
  2D plot as the accelerometer's (:func:`viewer.lcurve._log_lcurve_plot`).

The 3D scenes hold every k-th sample, at most :data:`MAG_POINTS`; the norm is an envelope
past ``SCREEN_ROWS`` (:mod:`viewer.decimate`). Nothing is logged without a magnetometer.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import rerun as rr

from . import paths as P
from .columns import (
    AFTER,
    BEFORE,
    CALIBRATED,
    GREY,
    RAW,
    nan_if_none,
    rgba,
    send_scalars,
    style_lines,
    style_points,
)
from .decimate import SCREEN_ROWS, envelope

if TYPE_CHECKING:
    from imucal.result import Result
    from imucal.stages.mag import MagFit
    from imucal.streams import Stream

MAG_POINTS = 3000  # samples drawn in each 3D scene, at most
LEFT_OUT = BEFORE
# Points and lines sized on the screen (negative radii: UI points), whatever the field's unit
# (gauss, uT, counts) and the zoom: a size in the scene's unit was invisible or a blob.
POINT = -2.5
LINE = -0.75


def mag_stream(result: Result) -> tuple[MagFit, Stream] | None:
    """The magnetometer's fit and the stream it was fitted to, or None without one."""
    fit = result.magnetometer
    if fit is None:
        return None
    stream = next((s for s in result.session.others if s.name == fit.stream), None)
    return None if stream is None else (fit, stream)


def shown_samples(fit: MagFit, stream: Stream) -> np.ndarray:
    """Indices of the samples drawn in the 3D scenes: every k-th finite one, at most
    :data:`MAG_POINTS`."""
    finite = np.flatnonzero(np.isfinite(np.asarray(stream.values, float)).all(axis=1))
    return finite[::max(1, -(-len(finite) // MAG_POINTS))]


def unit_circles(n: int = 96) -> list[np.ndarray]:
    """Unit directions on a wireframe: the three great circles of the axes and the circles at
    45 deg above and below the x-y plane."""
    a = np.linspace(0, 2 * np.pi, n)
    c, s, z = np.cos(a), np.sin(a), np.zeros(n)
    r = np.sqrt(0.5)
    return [np.column_stack(v) for v in ((c, s, z), (c, z, s), (z, c, s),
                                         (r * c, r * s, z + r), (r * c, r * s, z - r))]


def log_magnetometer(result: Result, rec: rr.RecordingStream, rows: dict[str, int]) -> None:
    found = mag_stream(result)
    if found is None:
        return
    fit, stream = found
    raw = np.asarray(stream.values, float)
    t = np.asarray(stream.t, float)
    unit = fit.unit or "raw unit"
    idx = shown_samples(fit, stream)
    used = fit.used[idx]
    colors = rgba(np.where(used, RAW, LEFT_OUT).tolist())
    rec.log(P.MAG_RAW_SAMPLES, rr.Points3D(raw[idx], colors=colors, radii=POINT),
            rr.AnyValues(sample_index=idx, used=used), static=True)
    rec.log(P.MAG_RAW_ELLIPSOID, rr.LineStrips3D([fit.ellipsoid(u) for u in unit_circles()],
                                                 colors=rgba([GREY] * 5),
                                                 radii=LINE), static=True)
    cal_colors = rgba(np.where(used, CALIBRATED, LEFT_OUT).tolist())
    rec.log(P.MAG_CAL_SAMPLES, rr.Points3D(fit.apply(raw[idx]), colors=cal_colors,
                                           radii=POINT),
            rr.AnyValues(sample_index=idx, used=used), static=True)
    rec.log(P.MAG_CAL_SPHERE, rr.LineStrips3D([fit.field * u for u in unit_circles()],
                                              colors=rgba([GREY] * 5),
                                              radii=LINE), static=True)

    err = 100.0 * fit.norm_error(raw)  # NaN on the rows that are not finite
    ok = np.isfinite(err) & np.isfinite(t)
    for path, mask, name, color in ((P.MAG_NORM_USED, ok & fit.used, "used (%)", CALIBRATED),
                                    (P.MAG_NORM_LEFT_OUT, ok & ~fit.used, "left out (%)",
                                     LEFT_OUT)):
        if mask.any():
            tt, ee = envelope(t[mask], err[mask], SCREEN_ROWS)
            rows[path] = send_scalars(rec, path, tt, ee)
            style_points(rec, path, [name], [color], size=1.5)
    _log_disturbed(fit, rec, rows)
    _log_dips(fit, t[ok], rec, rows)
    _log_info(fit, unit, len(idx), rec)
    if fit.lcurve is not None:
        from .layout import MAG_LCURVE_BOX
        from .lcurve import _log_lcurve_plot

        _log_lcurve_plot(rec, [(P.MAG_LCURVE_POINTS, fit.lcurve, CALIBRATED, "magnetometer")],
                         P.MAG_LCURVE, MAG_LCURVE_BOX, "|M / (tr M / 3) − I|")


def _log_disturbed(fit: MagFit, rec: rr.RecordingStream, rows: dict[str, int]) -> None:
    """The disturbed parts as a lane: each one's kind from its start, reset at its end (in
    time order; one that starts inside another ends the other's bar there)."""
    if not fit.disturbances:
        return
    order = sorted(fit.disturbances, key=lambda d: (d.t_start, d.t_end))
    times = np.array([[d.t_start, d.t_end] for d in order], float).ravel()
    states = [s for d in order for s in (d.kind, "")]
    kinds = ["norm", "dip", "step"]
    rec.log(P.MAG_DISTURBED, rr.StateConfiguration(
        values=kinds, labels=["norm off", "dip off", "field stepped"],
        colors=rgba([LEFT_OUT, 0xF28E2BFF, 0xB07AA1FF])), static=True)
    rec.send_columns(P.MAG_DISTURBED, indexes=[rr.TimeColumn(P.TIME, duration=times)],
                     columns=rr.StateChange.columns(state=states))
    rows[P.MAG_DISTURBED] = len(times)


def _log_dips(fit: MagFit, t: np.ndarray, rec: rr.RecordingStream, rows: dict[str, int]
              ) -> None:
    if fit.block_times is None or not np.isfinite(fit.block_dip_deg).any():
        return
    mid = fit.block_times.mean(axis=1)
    dip = fit.block_dip_deg
    have = np.isfinite(dip)
    for path, mask, name, color in ((P.MAG_DIP_USED, have & fit.block_used, "used (deg)",
                                     AFTER),
                                    (P.MAG_DIP_LEFT_OUT, have & ~fit.block_used,
                                     "left out (deg)", LEFT_OUT)):
        if mask.any():
            rows[path] = send_scalars(rec, path, mid[mask], dip[mask])
            style_points(rec, path, [name], [color])
    if fit.dip_deg is not None and len(t):
        rows[P.MAG_DIP_FIT] = send_scalars(rec, P.MAG_DIP_FIT, [t[0], t[-1]],
                                           np.full(2, fit.dip_deg))
        style_lines(rec, P.MAG_DIP_FIT, [f"fitted dip {fit.dip_deg:.2f} deg"], [GREY],
                    width=1.5)


def _log_info(fit: MagFit, unit: str, shown: int, rec: rr.RecordingStream) -> None:
    q = fit.quality
    rec.log(P.MAG_INFO, rr.AnyValues(
        stream=fit.stream, unit=unit, field=fit.field, std_field=fit.std_field,
        dip_deg=nan_if_none(fit.dip_deg), std_dip_deg=nan_if_none(fit.std_dip_deg),
        norm_rms_pct=q.norm_rms_pct,
        norm_rms_held_out_pct=nan_if_none(q.norm_rms_held_out_pct),
        dip_spread_deg=nan_if_none(q.dip_spread_deg), coverage=q.coverage,
        missing=q.missing or "", blocks=q.blocks, samples=fit.samples,
        samples_used=int(fit.used.sum()), points_shown=shown,
        disturbances=[d.text() for d in fit.disturbances] or [""]), static=True)
    rec.log(P.MAG_NOTE, rr.TextDocument(mag_note(fit), media_type="text/markdown"),
            static=True)


def mag_note(fit: MagFit) -> str:
    """The tab's note (markdown): the figures, the coverage and what is missing, and the
    parts of the recording left out, as the core states them."""
    q = fit.quality
    unit = fit.unit or "raw unit"
    lines = [f"**Magnetometer** `{fit.stream}`: field {fit.field:.4g} ± {fit.std_field:.2g} "
             f"{unit}" + ("" if fit.dip_deg is None else
                          f", dip {fit.dip_deg:.2f} ± {fit.std_dip_deg:.2f} deg"), "",
             f"- norm residual RMS {q.norm_rms_pct:.3g} %"
             + ("" if q.norm_rms_held_out_pct is None
                else f" in-sample, {q.norm_rms_held_out_pct:.3g} % held out"),
             f"- coverage: the field reached {q.coverage:.0%} of directions"
             + ("" if q.missing is None else f"; {q.missing}")]
    if fit.lam is not None and fit.lcurve is not None:
        lines.append(f"- soft iron held towards a sphere with λ = {fit.lam:.3g} "
                     + ("(no corner: the data determine it)" if fit.lcurve.well_posed
                        else "(the L-curve's corner)")
                     + ("" if not fit.undetermined else
                        f"; not determined by this recording: {', '.join(fit.undetermined)}"))
    if q.dip_spread_deg is not None:
        lines.append(f"- dip spread over {q.blocks} still blocks {q.dip_spread_deg:.3g} deg")
    if (a := fit.alignment) is not None:
        lines.append(f"- rotation to the accelerometer from the {a.evidence}"
                     + ("" if not a.turns else f" ({a.turns} turns, {a.turns_share:.0%} of "
                        "its information)"))
    left = fit.samples - int(fit.used.sum())
    if fit.disturbances:
        lines.append(f"- left out ({left} samples): "
                     + "; ".join(d.text() for d in fit.disturbances))
    return "\n".join(lines)


def mag_titles(result: Result) -> tuple[str, str]:
    """The two 3D scenes' titles: what is drawn and the coverage / the norm residual."""
    fit = result.magnetometer
    unit = "" if fit is None or fit.unit is None else f" ({fit.unit})"
    cov = "" if fit is None else f", coverage {fit.quality.coverage:.0%}"
    rms = "" if fit is None else f", norm RMS {fit.quality.norm_rms_pct:.2g} %"
    return (f"Raw field{unit}: used orange, left out red; fitted ellipsoid grey{cov}",
            f"Calibrated field{unit} on the sphere |m| = F: left out red{rms}")
