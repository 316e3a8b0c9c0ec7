"""Arrays read a block of rows at a time (issue 12: a 6-hour 1 kHz session in 1.5 GB).

A signal may be a disk-backed array that offers only ``len``, ``shape``, ``ndim``, ``dtype``,
contiguous row slices ``x[a:b]`` (and ``x[a:b, j]``), each a fresh C-ordered ndarray, and
integer-array gathers ``x[idx]``; ``np.asarray(x)`` would read it whole. The helpers here read
such arrays through slices and gathers only, :data:`ROWS` rows at a time at most, and give what
numpy's whole-array call gives, to the bit.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

ROWS = 1 << 18  # rows read at once (6 MB of float64 triples)


def blocks(n: int, rows: int = ROWS, start: int = 0) -> Iterator[tuple[int, int]]:
    """``[a, b)`` row ranges of at most ``rows`` rows covering ``[start, n)``, in order."""
    for a in range(start, n, rows):
        yield a, min(a + rows, n)


def floats(x, a: int, b: int) -> np.ndarray:
    """Rows ``[a, b)`` of ``x`` as float64 (a view of an in-memory float64 array: read only)."""
    return np.asarray(x[a:b], dtype=np.float64)


def value_at(x, i: int):
    """``x[i]`` (a row, or a scalar of a 1-D array) through a slice; negative ``i`` counts from
    the end, as numpy's."""
    n = len(x)
    j = i + n if i < 0 else i
    if not 0 <= j < n:
        raise IndexError(f"index {i} is out of bounds for {n} rows")
    return x[j:j + 1][0]


def search_sorted(t, values, side: str = "left", rows: int = 1 << 16) -> np.ndarray:
    """``np.searchsorted(t, values, side)`` for an ascending ``t`` read through slices: the
    block of each value from a gather of every ``rows``-th element, then the position inside
    that block's slice (each block read once, only the blocks some value falls in)."""
    values = np.asarray(values, dtype=np.float64)
    if isinstance(t, np.ndarray):
        return np.searchsorted(t, values, side=side)
    n = len(t)
    flat = values.ravel()
    out = np.zeros(len(flat), dtype=np.intp)
    if n == 0 or len(flat) == 0:
        return out.reshape(values.shape)
    coarse = np.asarray(t[np.arange(0, n, rows)], dtype=np.float64)
    block = np.searchsorted(coarse, flat, side=side) - 1  # -1: before t[0] (answer 0)
    for j in np.unique(block[block >= 0]).tolist():
        a = j * rows
        seg = np.asarray(t[a:min(a + rows, n)], dtype=np.float64)
        here = block == j
        out[here] = a + np.searchsorted(seg, flat[here], side=side)
    return out.reshape(values.shape)


def strictly_increasing(t, rows: int = ROWS) -> bool:
    """``bool(len(t) > 1 and np.all(np.diff(t) > 0))``, a block of ``t`` at a time."""
    n = len(t)
    if n < 2:
        return False
    for a, b in blocks(n - 1, rows):
        if not np.all(np.diff(np.asarray(t[a:b + 1], dtype=np.float64)) > 0):
            return False
    return True


def column_extremes(x, rows: int = ROWS) -> tuple[np.ndarray, np.ndarray]:
    """``(x.min(axis=0), x.max(axis=0))`` of an (n, k) array, a block of rows at a time (a NaN
    makes its column's extremes NaN, as numpy's)."""
    lo = hi = None
    for a, b in blocks(len(x), rows):
        c = np.asarray(x[a:b])
        # Column by column: numpy reduces an (n, 3) array along its rows 40x slower.
        cl = np.array([c[:, j].min() for j in range(c.shape[1])], dtype=c.dtype)
        ch = np.array([c[:, j].max() for j in range(c.shape[1])], dtype=c.dtype)
        lo = cl if lo is None else np.minimum(lo, cl)
        hi = ch if hi is None else np.maximum(hi, ch)
    if lo is None:
        raise ValueError("zero-size array has no extremes")
    return lo, hi


def rows_where(x, keep, rows: int = ROWS) -> np.ndarray:
    """``x[keep(t_block)]`` gathered a block at a time: ``keep(a, b)`` gives the boolean mask
    of rows ``[a, b)``; the rows kept, in order."""
    parts = []
    for a, b in blocks(len(x), rows):
        m = keep(a, b)
        if m.any():
            parts.append(np.asarray(x[a:b])[m])
    if parts:
        return np.concatenate(parts)
    return np.zeros((0,) + tuple(x.shape[1:]), dtype=x.dtype)


def pairwise_sum(values, n: int, leaf: int | None = None) -> float:
    """``np.add.reduce`` of the ``n`` values ``values(a, b)`` gives ``[a, b)`` at a time (1-D
    float64), to the bit: numpy sums a contiguous array pairwise, halving it (to a multiple of
    8) until a part is short; the parts of at most ``leaf`` values are summed by numpy itself
    and joined as its halving joins them (``leaf``: :data:`ROWS`)."""
    leaf = max(ROWS if leaf is None else leaf, 128)  # numpy halves only above 128 values
    if n <= leaf:
        return float(np.add.reduce(values(0, n))) if n else 0.0

    def part(s: int, m: int):
        if m <= leaf:
            return np.add.reduce(values(s, s + m))
        half = m // 2
        half -= half % 8
        return part(s, half) + part(s + half, m - half)

    return float(part(0, n))


class RowRange:
    """Rows ``[a, b)`` of ``x`` as an array-like read through slices (``len``, ``shape``,
    ``r[i:j]``): a long stretch handed on without reading it."""

    def __init__(self, x, a: int, b: int):
        self.x, self.a, self.b = x, int(a), int(b)

    def __len__(self) -> int:
        return self.b - self.a

    @property
    def shape(self) -> tuple[int, ...]:
        return (self.b - self.a,) + tuple(self.x.shape[1:])

    def __getitem__(self, key):
        if not (isinstance(key, slice) and key.step in (None, 1)):
            raise TypeError("a RowRange is read through contiguous slices")
        i, j, _ = key.indices(len(self))
        return self.x[self.a + i:self.a + max(i, j)]
