"""How the viewer logs: columns in chunks, the styles of its series, its colours.

Nothing here knows what is logged; the tab modules (:mod:`viewer.signals`,
:mod:`viewer.gravity`, :mod:`viewer.lcurve`, :mod:`viewer.optimiser`, :mod:`viewer.summary`)
map a result's arrays onto paths with these.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import rerun as rr

from . import paths as P

CHUNK_ROWS = 100_000

# Colours (RGBA)
RAW = 0xFF7F0EFF
CALIBRATED = 0x1F77B4FF
MEASURED = 0x2CA02CFF
BEFORE = 0xD62728FF
AFTER = 0x1F77B4FF
PREVIOUS = 0x9E9E9EFF
XYZ = [0xE15759FF, 0x59A14FFF, 0x4E79A7FF]
STILL = 0x59A14FFF
SEGMENT_COLORS = [0x4E79A7FF, 0xF28E2BFF, 0x76B7B2FF, 0xB07AA1FF, 0xEDC948FF, 0xFF9DA7FF]
BETWEEN = 0xBAB0ACFF
CORNER = 0xD62728FF
GREY = 0x808080FF


def _chunks(n: int, size: int = CHUNK_ROWS) -> Iterator[slice]:
    for i in range(0, n, size):
        yield slice(i, min(i + size, n))


def send_scalars(rec: rr.RecordingStream, path: str, index: np.ndarray, values: np.ndarray,
                 timeline: str = P.TIME) -> int:
    """Scalars (one per row, or k per row for (N, k) values) in chunks; returns rows sent."""
    values = np.asarray(values, dtype=np.float64)
    index = np.asarray(index)
    for s in _chunks(len(index)):
        if timeline == P.TIME:
            col = rr.TimeColumn(timeline, duration=index[s])
        else:
            col = rr.TimeColumn(timeline, sequence=index[s])
        rec.send_columns(path, indexes=[col], columns=rr.Scalars.columns(scalars=values[s]))
    return len(index)


def rgba(colors: list[int]) -> np.ndarray:
    """0xRRGGBBAA values as the unambiguous array Rerun wants (3 ints could be one RGB)."""
    return np.asarray(colors, dtype=np.uint32)


def style_lines(rec: rr.RecordingStream, path: str, names: list[str], colors: list[int],
                width: float | None = None) -> None:
    widths = None if width is None else [width] * len(names)
    rec.log(path, rr.SeriesLines(names=names, colors=rgba(colors), widths=widths), static=True)


def style_points(rec: rr.RecordingStream, path: str, names: list[str], colors: list[int],
                 size: float = 4.0, marker: str = "circle") -> None:
    rec.log(path, rr.SeriesPoints(names=names, colors=rgba(colors), markers=[marker] * len(names),
                                  marker_sizes=[size] * len(names)), static=True)


def log10_axis(x: np.ndarray) -> np.ndarray:
    """Values for a log-scale plot (a Rerun time series has no log axis): log10 where
    positive, NaN (not drawn) elsewhere."""
    x = np.asarray(x, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(x > 0, np.log10(np.where(x > 0, x, 1.0)), np.nan)


def nan_if_none(x: float | None) -> float:
    """AnyValues have no None: a figure without a value is logged as NaN."""
    return float("nan") if x is None else float(x)
