"""The noise figures of ``imucal noise`` as a Rerun recording: log-log Allan deviation plots.

Reads the JSON-ready dict of :func:`imucal.io.noise_json.noise_to_dict` (nothing is computed
here but the drawing: the fitted lines are the fit's own terms evaluated on the taus).

=================================== ======= ==================================================
Entity path                          Time    Content
=================================== ======= ==================================================
noise/<sensor>/adev/<axis>           static  LineStrips2D + Points2D at (log10 tau, -log10
                                             sigma): the measured overlapping Allan deviation
                                             (y negated: 2D views draw y downwards)
noise/<sensor>/fit/white|random_walk static  LineStrips2D: the slope -1/2 line through N at
                                             tau = 1 s, the slope +1/2 line through K at 3 s
                                             (largest axis), where determined
noise/<sensor>/frame                 static  axes with decade tick labels
noise/<sensor>/values                static  AnyValues: tau_s, adev_x|y|z, white, random_walk,
                                             bias_instability (per axis, NaN: not determined)
noise/summary                        static  TextDocument (markdown): the figures with units
=================================== ======= ==================================================
"""

from __future__ import annotations

import os
import uuid

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from imucal.io.atomic import atomic_path, check_output_path

AXES = ("x", "y", "z")
COLORS = {"x": 0xE24A33FF, "y": 0x348ABDFF, "z": 0x55A868FF}
GREY = 0x808080FF
SENSORS = ("accelerometer", "gyroscope")


def _rgba(c: int) -> np.ndarray:
    return np.array([[(c >> 24) & 255, (c >> 16) & 255, (c >> 8) & 255, c & 255]],
                    dtype=np.uint8)


def _nan(values: list) -> np.ndarray:
    return np.array([np.nan if v is None else float(v) for v in values])


def _frame(rec: rr.RecordingStream, base: str, x0: float, x1: float, y0: float, y1: float,
           unit: str) -> None:
    """Axes and decade ticks in (log10 tau, -log10 sigma): a 2D view has none of its own."""
    pad = 0.1 * max(x1 - x0, y1 - y0, 1.0)
    left, right, top, bottom = x0 - pad, x1 + pad, -y1 - pad, -y0 + pad
    tick = 0.02 * (right - left)
    xt = np.arange(np.ceil(left), np.floor(right) + 1)
    yt = np.arange(np.ceil(y0 - pad), np.floor(y1 + pad) + 1)
    strips = [[[left, bottom], [right, bottom]], [[left, bottom], [left, top]]]
    strips += [[[x, bottom], [x, bottom + tick]] for x in xt]
    strips += [[[left, -y], [left - tick, -y]] for y in yt]
    rec.log(f"{base}/frame/axes", rr.LineStrips2D(strips, colors=_rgba(GREY),
                                                  radii=rr.Radius.ui_points(1.0)), static=True)
    pos = [[x, bottom + 3 * tick] for x in xt] + [[left - 4 * tick, -y] for y in yt]
    lab = [f"{10**x:g} s" for x in xt] + [f"1e{int(y)}" for y in yt]
    pos += [[(left + right) / 2, bottom + 7 * tick], [left, top - 3 * tick]]
    lab += ["tau (s, log scale) →", f"↑ Allan deviation ({unit}, log scale)"]
    rec.log(f"{base}/frame/labels", rr.Points2D(pos, labels=lab, colors=_rgba(GREY),
                                                radii=rr.Radius.ui_points(0.5),
                                                show_labels=True), static=True)


def _log_sensor(rec: rr.RecordingStream, name: str, sn: dict) -> None:
    base = f"noise/{name}"
    ad = sn["allan_deviation"]
    tau = np.array(ad["tau_s"], dtype=float)
    lt = np.log10(tau)
    ys = []
    for axis in AXES:
        dev = _nan(ad[axis])
        ok = np.isfinite(dev) & (dev > 0)
        pts = np.column_stack([lt[ok], -np.log10(dev[ok])])
        ys.append(np.log10(dev[ok]))
        rec.log(f"{base}/adev/{axis}", rr.LineStrips2D([pts], colors=_rgba(COLORS[axis]),
                                                       labels=[f"{name} {axis}"]), static=True)
        rec.log(f"{base}/adev/{axis}/points", rr.Points2D(pts, colors=_rgba(COLORS[axis]),
                                                          radii=rr.Radius.ui_points(3.0)),
                static=True)
    allys = np.concatenate(ys) if ys else np.zeros(1)
    lo, hi = float(allys.min()), float(allys.max())
    white = _nan(sn["white_noise_density"])
    rw = _nan(sn["random_walk"])
    x = np.linspace(lt.min(), lt.max(), 200)
    lines = {}
    if np.any(np.isfinite(white)):  # sigma = N / sqrt(tau)
        n = np.nanmax(white)
        lines["white"] = (np.log10(n) - 0.5 * x, f"N = {n:.3g} {sn['white_noise_density_unit']}")
    if np.any(np.isfinite(rw)):  # sigma = K sqrt(tau / 3)
        k = np.nanmax(rw)
        lines["random_walk"] = (np.log10(k) + 0.5 * (x - np.log10(3.0)),
                                f"K = {k:.3g} {sn['random_walk_unit']}")
    for key, (y, label) in lines.items():
        inside = (y >= lo - 0.3) & (y <= hi + 0.3)  # within the plotted range
        if np.count_nonzero(inside) > 1:
            rec.log(f"{base}/fit/{key}", rr.LineStrips2D(
                [np.column_stack([x[inside], -y[inside]])], colors=_rgba(GREY),
                labels=[label]), static=True)
    _frame(rec, base, float(lt.min()), float(lt.max()), lo, hi, sn["unit"])
    rec.log(f"{base}/values", rr.AnyValues(
        tau_s=tau, **{f"adev_{a}": _nan(ad[a]) for a in AXES}, white=white, random_walk=rw,
        bias_instability=_nan(sn["bias_instability"])), static=True)


def _cell(sn: dict, key: str, i: int) -> str:
    v = sn[key][i]
    return "n/a" if v is None else f"{v:.4g} {sn[key + '_unit']}"


def summary_markdown(data: dict) -> str:
    rows = ["| sensor | axis | white noise density | bias instability | random walk |",
            "|---|---|---|---|---|"]
    for name in SENSORS:
        sn = data.get(name)
        if not sn:
            continue
        for i, axis in enumerate(AXES):
            cells = [_cell(sn, key, i) for key in ("white_noise_density", "bias_instability",
                                                    "random_walk")]
            rows.append(f"| {name} | {axis} | " + " | ".join(cells) + " |")
    notes = [f"- {n}" for name in SENSORS if data.get(name) for n in data[name]["notes"]]
    return "\n".join([f"# Noise figures\n\n{data['source']}\n", *rows, "", *notes])


def blueprint(data: dict) -> rrb.Blueprint:
    views = [rrb.Spatial2DView(name=f"{name}: Allan deviation (log-log)",
                               origin=f"noise/{name}", contents=[f"noise/{name}/**"])
             for name in SENSORS if data.get(name)]
    return rrb.Blueprint(rrb.Vertical(rrb.Horizontal(*views),
                                      rrb.TextDocumentView(origin="noise/summary"),
                                      row_shares=[3, 1]), collapse_panels=True)


def save_noise_recording(data: dict, path: str | os.PathLike) -> None:
    """Write the plots of ``data`` to one ``.rrd`` file, atomically."""
    check_output_path(path)
    with atomic_path(path) as tmp:
        rec = rr.RecordingStream("imucal", recording_id=uuid.uuid4())
        rec.save(tmp, default_blueprint=blueprint(data))
        rec.send_recording_name("imucal noise")
        for name in SENSORS:
            if data.get(name):
                _log_sensor(rec, name, data[name])
        rec.log("noise/summary", rr.TextDocument(summary_markdown(data),
                                                 media_type=rr.MediaType.MARKDOWN), static=True)
        rec.flush()
        rec.disconnect()
        del rec
