"""Line plots drawn in a ``Spatial2DView``: series against their own axis (the lambda of the
L-curve sweep, the optimiser's accepted step), which a ``TimeSeriesView`` cannot show (it
always plots against the time cursor's timeline, so such a view opens empty on ``time``).

A plot is an entity tree under ``base``:

- ``base/frame``: axes, grid, tick marks and tick labels, in scene units;
- ``base/<series>``: one entity per series, ``Points2D`` (and a ``LineStrips2D``) at the data's
  own ``(x, y)`` with its own ``Transform3D`` from data coordinates to scene units, so a script
  reads the numbers back as logged (x is log10 of the value on a log axis);
- ``base/legend``: each series' name beside the end of its curve, nudged apart.

Scene units are about pixels at the default window size (1600x1000): the blueprint gives each
view its plot's :meth:`Box.bounds`, so labels, which keep their pixel size, land where they
were laid out. Everything here is drawing (ranges, ticks, label places), not results.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import rerun as rr

from .columns import GREY, rgba
from .layout import Box

CHAR_PX = 7.0  # width of a label's character at the default UI font, pixels
LABEL_PX = 18.0  # height of a label's box
LABEL_DROP = 11.0  # a point's label is drawn centred this far below the point (measured)
GRID = 0x2A2A2AFF
TEXT = 0xA0A0A0FF


@dataclass(frozen=True)
class Axis:
    """A data range with its ticks and their labels (``log``: the data are log10 values)."""

    lo: float
    hi: float
    ticks: np.ndarray
    labels: list[str]
    log: bool = False


@dataclass(frozen=True)
class Series:
    """One curve: ``name`` in the legend, ``path`` its entity under ``base/data``."""

    path: str
    name: str
    color: int
    x: np.ndarray
    y: np.ndarray
    values: dict = field(default_factory=dict)  # stored beside the points (AnyValues)
    line: bool = True
    size: float = 2.5  # point radius, UI points
    labels: list[str] | None = None  # per point, shown on the plot


@dataclass(frozen=True)
class Mark:
    """A vertical line at ``x`` (data) across the box, labelled at its top."""

    x: float
    label: str
    color: int


def label_width(text: str) -> float:
    return CHAR_PX * len(text) + 10.0


def nice_ticks(lo: float, hi: float, most: int = 5) -> np.ndarray:
    """Round ticks (1, 2, 2.5 or 5 times a power of ten) inside ``[lo, hi]``: 2 to ``most``."""
    span = hi - lo
    if not (math.isfinite(span) and span > 0):
        return np.array([lo])
    raw = span / max(most - 1, 1)
    mag = 10.0 ** math.floor(math.log10(raw))
    for m in (1.0, 2.0, 2.5, 5.0, 10.0):
        step = m * mag
        ticks = np.arange(math.ceil(lo / step - 1e-9), math.floor(hi / step + 1e-9) + 1) * step
        if len(ticks) <= most:
            return np.where(np.abs(ticks) < step * 1e-9, 0.0, ticks)
    return np.array([lo, hi])


def tick_labels(ticks: np.ndarray) -> list[str]:
    """Tick values with just the digits their spacing needs (0.97, 0.98; 5.7702e-04, ...)."""
    t = np.asarray(ticks, float)
    if len(t) < 2:
        return [f"{v:.4g}" for v in t]
    step = float(np.min(np.diff(t)))
    big = float(np.max(np.abs(t)))
    if not (step > 0 and big > 0):
        return [f"{v:.4g}" for v in t]
    decimals = max(0, -math.floor(math.log10(step) + 1e-9))
    if 1e-3 <= big < 1e6 and decimals <= 5:
        return [f"{v:.{decimals}f}" for v in t]
    digits = max(1, math.floor(math.log10(big)) - math.floor(math.log10(step) + 1e-9) + 1)
    return [_short_e(f"{v:.{digits - 1}e}") for v in t]


def _short_e(s: str) -> str:
    """5.7730e-04 -> 5.7730e-4: a tick label is read at a glance."""
    mantissa, e, exp = s.partition("e")
    return f"{mantissa}e{int(exp)}" if e else s


def linear_axis(values: np.ndarray, pad: float = 0.06, most: int = 5) -> Axis:
    """An axis over the finite ``values`` (any shape), padded by ``pad`` of the span."""
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    lo, hi = (float(v.min()), float(v.max())) if len(v) else (0.0, 1.0)
    if hi - lo <= 1e-12 * max(abs(lo), abs(hi), 1e-300):  # flat: a range around the value
        half = max(abs(lo) * 1e-3, 1e-12)
        lo, hi = lo - half, hi + half
    lo, hi = lo - pad * (hi - lo), hi + pad * (hi - lo)
    ticks = nice_ticks(lo, hi, most)
    return Axis(lo, hi, ticks, tick_labels(ticks))


def log_axis(log10_values: np.ndarray, pad: float = 0.04, most: int = 6,
             min_span: float = 0.0) -> Axis:
    """An axis over log10 values, ticked at decades (every few when there are many), else at
    1 and 3, or 1, 2 and 5 times them, else at round values within one decade. ``min_span``:
    at least that many decades, centred on the values (so a change of a fraction of a percent
    stays one)."""
    v = np.asarray(log10_values, float)
    v = v[np.isfinite(v)]
    lo, hi = (float(v.min()), float(v.max())) if len(v) else (0.0, 1.0)
    if hi - lo < max(min_span, 1e-9):
        mid, half = (lo + hi) / 2, max(min_span, 1.0) / 2
        lo, hi = mid - half, mid + half
    lo, hi = lo - pad * (hi - lo), hi + pad * (hi - lo)
    decades = range(math.floor(lo), math.ceil(hi) + 1)
    for mult in ((1.0,), (1.0, 3.0), (1.0, 2.0, 5.0)):
        t = np.log10([m * 10.0**d for d in decades for m in mult])
        t = t[(t >= lo - 1e-9) & (t <= hi + 1e-9)]
        if len(mult) == 1:
            t = t[::max(1, math.ceil(len(t) / most))]
        if 3 <= len(t) <= most:
            return Axis(lo, hi, t, [_short_e(f"{10.0**d:.3g}") for d in t], log=True)
    ticks = nice_ticks(10.0**lo, 10.0**hi, 4)
    ticks = ticks[ticks > 0]
    return Axis(lo, hi, np.log10(ticks), tick_labels(ticks), log=True)


def step_axis(n: int) -> Axis:
    """Integer steps 0 .. n-1 (the optimiser's accepted steps)."""
    hi = max(n - 1, 1)
    ticks = nice_ticks(0.0, float(hi), 6)
    ticks = ticks[np.isclose(ticks, np.round(ticks))]
    return Axis(-0.04 * hi, hi * 1.04, ticks, [f"{int(round(t))}" for t in ticks])


# --- logging --------------------------------------------------------------------------------


def _scene(box: Box, xa: Axis, ya: Axis) -> tuple[np.ndarray, np.ndarray]:
    """Scale and translation taking data (x, y) to scene units (y down)."""
    sx = box.width / (xa.hi - xa.lo)
    sy = -box.height / (ya.hi - ya.lo)
    return np.array([sx, sy]), np.array([-xa.lo * sx, box.height - ya.lo * sy])


def to_scene(box: Box, xa: Axis, ya: Axis, xy: np.ndarray) -> np.ndarray:
    scale, shift = _scene(box, xa, ya)
    return np.asarray(xy, float) * scale + shift


def text(rec: rr.RecordingStream, path: str, centres: list, labels: list[str],
          colors: list[int]) -> None:
    """Labels centred on ``centres`` (scene units): each on an invisible point above it."""
    pos = np.asarray(centres, float).reshape(-1, 2) - [0.0, LABEL_DROP]
    rec.log(path, rr.Points2D(pos, labels=labels,
                              colors=rgba(colors), radii=rr.Radius.ui_points(0.0),
                              show_labels=True, draw_order=40.0), static=True)


def log_frame(rec: rr.RecordingStream, base: str, box: Box, xa: Axis, ya: Axis,
              grid: bool = True) -> None:
    """Axes along the left and bottom, a faint grid at the ticks, the tick labels."""
    w, h = box.width, box.height
    xs = to_scene(box, xa, ya, np.column_stack([xa.ticks, np.zeros(len(xa.ticks))]))[:, 0]
    ys = to_scene(box, xa, ya, np.column_stack([np.zeros(len(ya.ticks)), ya.ticks]))[:, 1]
    if grid:
        lines = [[[0, y], [w, y]] for y in ys] + [[[x, 0], [x, h]] for x in xs]
        rec.log(f"{base}/frame/grid", rr.LineStrips2D(lines, colors=rgba([GRID]),
                                                      radii=rr.Radius.ui_points(0.5),
                                                      draw_order=1.0), static=True)
    axes = [[[0, 0], [0, h], [w, h]]]
    axes += [[[x, h], [x, h + 5]] for x in xs] + [[[0, y], [-5, y]] for y in ys]
    rec.log(f"{base}/frame/axes", rr.LineStrips2D(axes, colors=rgba([GREY]),
                                                  radii=rr.Radius.ui_points(0.75),
                                                  draw_order=2.0), static=True)
    pos = [[x, h + 15] for x in xs]
    pos += [[-8 - label_width(t) / 2, y] for y, t in zip(ys, ya.labels)]
    text(rec, f"{base}/frame/ticks", pos, xa.labels + ya.labels, [TEXT])


def _legend_places(ends: np.ndarray, top: float, bottom: float) -> np.ndarray:
    """Label centres near ``ends`` (scene y), at least a label apart, within [top, bottom]
    where they fit: a forward then a backward sweep over the sorted ends."""
    order = np.argsort(ends, kind="stable")
    y = np.clip(ends[order], top, bottom).astype(float)
    gap = min(LABEL_PX + 3.0, (bottom - top) / max(len(y) - 1, 1))  # boxes drawn ~19 px
    for i in range(1, len(y)):
        y[i] = max(y[i], y[i - 1] + gap)
    y[-1:] = np.minimum(y[-1:], bottom)
    for i in range(len(y) - 2, -1, -1):
        y[i] = min(y[i], y[i + 1] - gap)
    out = np.empty_like(y)
    out[order] = y
    return out


def log_plot(rec: rr.RecordingStream, base: str, box: Box, xa: Axis, ya: Axis,
             series: Sequence[Series], marks: Sequence[Mark] = (), legend: bool = True) -> None:
    """The frame, the series (in data coordinates, each with its transform to the scene),
    marks and legend."""
    log_frame(rec, base, box, xa, ya)
    scale, shift = _scene(box, xa, ya)
    to_box = rr.Transform3D(translation=[shift[0], shift[1], 0.0],
                            scale=[scale[0], scale[1], 1.0])
    ends, names, colors = [], [], []
    for s in series:
        xy = np.column_stack([s.x, s.y]).astype(float)
        ok = np.all(np.isfinite(xy), axis=1)
        path = f"{base}/{s.path}"
        extra = [rr.AnyValues(**s.values)] if s.values else []
        rec.log(path, to_box, static=True)
        rec.log(path, rr.Points2D(xy, colors=rgba([s.color]),
                                  radii=rr.Radius.ui_points(s.size), labels=s.labels,
                                  show_labels=s.labels is not None, draw_order=20.0),
                *extra, static=True)
        if s.line and ok.sum() > 1:
            rec.log(path, rr.LineStrips2D([xy[ok]], colors=rgba([s.color]),
                                          radii=rr.Radius.ui_points(1.0), draw_order=15.0),
                    static=True)
        if ok.any():
            ends.append(to_scene(box, xa, ya, xy[ok][-1:])[0, 1])
            names.append(s.name)
            colors.append(s.color)
    for i, m in enumerate(marks):
        x = float(to_scene(box, xa, ya, [[m.x, ya.lo]])[0, 0])
        rec.log(f"{base}/frame/mark_{i}", rr.LineStrips2D(
            [[[x, 0], [x, box.height]]], colors=rgba([m.color]), radii=rr.Radius.ui_points(0.75),
            draw_order=5.0), static=True)
        if m.label:
            text(rec, f"{base}/frame/mark_{i}/label", [[x + 4 + label_width(m.label) / 2, 10]],
                  [m.label], [m.color])
    if legend and names:
        ys = _legend_places(np.asarray(ends), -box.top + LABEL_PX / 2,
                            box.height + box.bottom - LABEL_PX / 2)
        pos = [[box.width + 10 + label_width(n) / 2, y] for n, y in zip(names, ys)]
        text(rec, f"{base}/legend", pos, names, colors)
