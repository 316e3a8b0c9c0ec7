"""A bucket's samples and step times read a slab of rows at a time, on request (method.md M5;
issue 12): what a bucket keeps is each interval's first sample and step count, so the arrays
laid out time-major (:mod:`.buckets`) never exist whole, only a block of a few slabs.

A block's rows are read from the source arrays once for every component and the timestamps:
from an ndarray as one run of rows per interval (through a strided view), from any other
array by one gather with a 1-D integer array (all an array kept on disk need offer, with
``len`` and ``.shape``). Every slab holds the same values, to the bit, as the same rows of
:func:`.buckets.lay_out`'s arrays, so whatever is computed from a slab is unchanged.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import NamedTuple

import numpy as np
from numpy.lib.stride_tricks import as_strided

from imucal.numerics.rk4.buckets import Bucket
from imucal.numerics.rk4.hamilton import Vec

# Elements (rows x intervals) evaluated at once: large enough that numpy's per-call overhead
# is small, small enough that the ~20 live temporaries stay in cache (measured in bench/).
SLAB = 32768


def slab_ranges(length: int, width: int) -> Iterator[tuple[int, int]]:
    """The steps ``r0 .. r1 - 1`` of each slab of a bucket of ``length`` steps and ``width``
    intervals. The slabs depend on the layout only (not on the models integrated), so the
    reduction tree, and the rounding, of every pass over a bucket is the same."""
    rows = max(1, SLAB // max(width, 1))
    for r0 in range(0, length, rows):
        yield r0, min(r0 + rows, length)


class Slab(NamedTuple):
    """Rows ``r0 .. r1`` of a bucket: the samples ``w`` ((m + 1, K_b) per component, zero in
    the padding), the steps' ``dt`` and ``dt2 = dt * dt`` ((m, K_b), 0 in the padding) and,
    when asked for, ``dt_next`` (K_b,), the step after the slab (0 past the last)."""

    w: Vec
    dt: np.ndarray
    dt2: np.ndarray
    dt_next: np.ndarray | None = None


class ArrayRows:
    """:class:`Slab` s of a bucket laid out whole (:func:`.buckets.lay_out`, the samples from
    ``StepLayout.gather``): views of its arrays."""

    def __init__(self, w: Vec, dt: np.ndarray, dt2: np.ndarray):
        self.w, self.dt, self.dt2 = w, dt, dt2

    def slab(self, r0: int, r1: int, ahead: bool = False) -> Slab:
        nxt = None
        if ahead:
            nxt = self.dt[r1] if r1 < self.dt.shape[0] else np.zeros(self.dt.shape[1])
        return Slab(tuple(x[r0:r1 + 1] for x in self.w), self.dt[r0:r1], self.dt2[r0:r1], nxt)


def _padding(n_steps: np.ndarray, shortest: int, r0: int, r1: int) -> np.ndarray | None:
    """Where rows ``r0 .. r1 - 1`` (r1 - r0, K_b) are padding (None when none is)."""
    if r1 - 1 <= shortest:
        return None
    return np.arange(r0, r1)[:, None] > n_steps


def _sample_index(starts: np.ndarray, n_steps: np.ndarray, shortest: int, r0: int, r1: int
                  ) -> tuple[np.ndarray, np.ndarray | None]:
    """Sample index (r1 - r0, K_b) of rows ``r0 .. r1 - 1`` and where they are padding (None
    when none is). Padding rows read the interval's last sample: in range, and a step between
    two of them is exactly 0 (``x - x = +0``), what :func:`.buckets.lay_out` gives padding."""
    idx = starts + np.arange(r0, r1)[:, None]
    pad = _padding(n_steps, shortest, r0, r1)
    if pad is not None:
        np.minimum(idx, starts + n_steps, out=idx)
    return idx, pad


def _rows_at(x, idx: np.ndarray) -> np.ndarray:
    """``x[idx]`` as float64 for a 1-D integer index: ``np.take`` for an ndarray (about three
    times faster than indexing for the rows of a 2-D array), indexing for any other array."""
    g = np.take(x, idx, axis=0) if isinstance(x, np.ndarray) else x[idx]
    return np.asarray(g, dtype=float)  # exact: a float gather


def _runs(x: np.ndarray, first: np.ndarray, span: int) -> np.ndarray:
    """Rows ``first[k] .. first[k] + span - 1`` of the ndarray ``x`` for every k, (K, span,
    ...): one copy of K contiguous runs through a strided view (no copy of ``x``)."""
    view = as_strided(x, shape=(len(x) - span + 1, span) + x.shape[1:],
                      strides=(x.strides[0],) + x.strides, writeable=False)
    return np.asarray(view[first], dtype=float)


class _Block(NamedTuple):
    """Sample rows ``lo .. hi - 1`` of a bucket: ``w`` (C, hi - lo, K_b), zero in the padding,
    and the steps between them, ``dt`` (hi - lo - 1, K_b), 0 in the padding."""

    lo: int
    hi: int
    w: np.ndarray
    dt: np.ndarray


# Rows of each interval read from the source at once, at least: as many slabs as that takes.
# Runs of a few rows from thousands of places are bound by the memory's latency: at 6 h, 1 kHz
# (9 rows a slab) a pass's reads took 0.52 s a slab at a time, 0.26 s in runs of 18 rows (2
# slabs, 2 MB held: the stage's memory peak stays under main's; runs of 36 gain a little more
# for 2 MB more).
RUN = 16


class LazyRows:
    """:class:`Slab` s of a bucket gathered from the source when read: the samples from ``x``
    (N, C) (the C components of a sample are one row), the step times from ``t`` (N,); neither
    is copied or converted whole. A block of slabs of at least :data:`RUN` rows is read at a
    time (a few slabs' worth at most, let go after the bucket's last slab)."""

    def __init__(self, x, t, starts: np.ndarray, n_steps: np.ndarray, length: int):
        self.x, self.t, self.starts, self.n_steps = x, t, starts, n_steps
        self.shortest = int(n_steps.min()) if len(n_steps) else 0
        self.shape = (length + 1, len(starts))
        rows = max(1, SLAB // max(len(starts), 1))  # a slab's (slab_ranges)
        self.block_rows = -(-RUN // rows) * rows + 2
        self._block: _Block | None = None

    def slab(self, r0: int, r1: int, ahead: bool = False) -> Slab:
        hi = r1 + 1 + ahead  # sample rows r0 .. hi - 1: row L + 1 is padding for all
        if self._block is None or r0 < self._block.lo or hi > self._block.hi:
            self._block = None  # let the last block go before reading the next
            self._block = self._read(r0, max(hi, min(r0 + self.block_rows, self.shape[0] + 1)))
        b = self._block
        if r1 >= self.shape[0] - 1:  # the bucket's last slab
            self._block = None
        i, m = r0 - b.lo, r1 - r0
        dt = b.dt[i:i + m]
        return Slab(tuple(b.w[:, i:i + m + 1]), dt, dt * dt, b.dt[i + m] if ahead else None)

    def _read(self, lo: int, hi: int) -> _Block:
        """Sample rows ``lo .. hi - 1``: runs of rows of an ndarray source (when no run passes
        its end), one gather of every sample otherwise; the same values either way."""
        first = self.starts + lo
        kb, span = len(first), hi - lo
        if (isinstance(self.x, np.ndarray) and isinstance(self.t, np.ndarray)
                and kb and int(first.max()) + span <= len(self.t)):
            pad = _padding(self.n_steps, self.shortest, lo, hi)
            g = _runs(self.x.reshape(len(self.x), -1), first, span)  # (K_b, span, C)
            w = np.ascontiguousarray(g.transpose(2, 1, 0))  # (C, span, K_b)
            del g
            tt = _runs(self.t, first, span)
            dt = np.ascontiguousarray((tt[:, 1:] - tt[:, :-1]).T)  # lay_out's subtraction
        else:  # any other array: one gather; a padding row reads the interval's last sample
            idx, pad = _sample_index(self.starts, self.n_steps, self.shortest, lo, hi)
            tt = _rows_at(self.t, idx.ravel()).reshape(idx.shape)
            dt = tt[1:] - tt[:-1]
            w = np.ascontiguousarray(_rows_at(self.x, idx.ravel()).reshape(span * kb, -1).T)
            w = w.reshape(-1, span, kb)  # (C, span, K_b): one array per component
        if pad is not None:
            np.copyto(w, 0.0, where=pad[None])
            np.copyto(dt, 0.0, where=pad[1:])  # lay_out's padding steps are 0
        return _Block(lo, hi, w, dt)


class LazySteps:
    """A bucket's step times ``dt`` ((L, K_b), 0 for padding), or ``dt^2``, read by slices of
    rows, from the timestamps ``t``."""

    def __init__(self, t, starts: np.ndarray, n_steps: np.ndarray, length: int,
                 squared: bool = False):
        self.rows = LazyRows(None, t, starts, n_steps, length)
        self.squared = squared
        self.shape = (length, len(starts))
        self.size = self.shape[0] * self.shape[1]

    def __getitem__(self, key: slice) -> np.ndarray:
        if not isinstance(key, slice) or key.step not in (None, 1):
            raise TypeError("lazily gathered rows are read by contiguous slices of rows")
        r0, r1, _ = key.indices(self.shape[0])
        r1 = max(r1, r0)
        rows = self.rows
        idx, _ = _sample_index(rows.starts, rows.n_steps, rows.shortest, r0, r1 + 1)
        tt = _rows_at(rows.t, idx.ravel()).reshape(idx.shape)
        dt = tt[1:] - tt[:-1]
        return dt * dt if self.squared else dt


def lay_out_lazy(t, starts: np.ndarray, n_steps: np.ndarray, idx: np.ndarray) -> Bucket:
    """:func:`.buckets.lay_out` without its arrays: ``i0`` and ``valid`` are None, ``dt`` and
    ``dt2`` are :class:`LazySteps` (the samples: :func:`lazy_rows`)."""
    L = int(max(n_steps[idx].max(), 1))
    s, n = starts[idx], n_steps[idx]
    return Bucket(idx, None, None, LazySteps(t, s, n, L), LazySteps(t, s, n, L, squared=True))


def lazy_rows(bucket: Bucket, x) -> LazyRows:
    """The slabs of a :func:`lay_out_lazy` bucket, its samples read from ``x`` (N, C)."""
    steps = bucket.dt.rows
    return LazyRows(x, steps.t, steps.starts, steps.n_steps, bucket.dt.shape[0])


def slab_rows(bucket: Bucket, w) -> ArrayRows | LazyRows:
    """The slabs of ``bucket`` with its samples ``w``: a :class:`LazyRows` as it is, a tuple
    of arrays laid out whole (``StepLayout.gather``) with the bucket's own ``dt``."""
    return w if isinstance(w, LazyRows) else ArrayRows(w, bucket.dt, bucket.dt2)
