"""A bucket's samples and step times read a slab of rows at a time, on request (method.md M5;
issue 12): what a bucket keeps is each interval's first sample and step count, so the arrays
laid out time-major (:mod:`.buckets`) never exist whole, only the slab being integrated.

A slab's rows are found once and read from the source arrays in one gather each (all the
components of a sample at once, then the timestamps): the source is only ever read by
``len``, ``.shape`` and a gather with a 1-D integer array, which an array kept on disk offers
as well as an ndarray. Every slab holds the same values, to the bit, as the same rows of
:func:`.buckets.lay_out`'s arrays, so whatever is computed from a slab is unchanged.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import NamedTuple

import numpy as np

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


def _sample_index(starts: np.ndarray, n_steps: np.ndarray, shortest: int, r0: int, r1: int
                  ) -> tuple[np.ndarray, np.ndarray | None]:
    """Sample index (r1 - r0, K_b) of rows ``r0 .. r1 - 1`` and where they are padding (None
    when none is). Padding rows read the interval's last sample: in range, and a step between
    two of them is exactly 0 (``x - x = +0``), what :func:`.buckets.lay_out` gives padding."""
    j = np.arange(r0, r1)[:, None]
    idx = starts + j
    if r1 - 1 <= shortest:
        return idx, None
    np.minimum(idx, starts + n_steps, out=idx)
    return idx, j > n_steps


class LazyRows:
    """:class:`Slab` s of a bucket gathered from the source when read: the samples from ``x``
    (N, C) (the C components of a sample are one row), the step times from ``t`` (N,); neither
    is copied or converted whole."""

    def __init__(self, x, t, starts: np.ndarray, n_steps: np.ndarray, length: int):
        self.x, self.t, self.starts, self.n_steps = x, t, starts, n_steps
        self.shortest = int(n_steps.min()) if len(n_steps) else 0
        self.shape = (length + 1, len(starts))

    def slab(self, r0: int, r1: int, ahead: bool = False) -> Slab:
        idx, pad = _sample_index(self.starts, self.n_steps, self.shortest, r0, r1 + 1 + ahead)
        flat = idx.ravel()
        tt = np.asarray(self.t[flat], dtype=float).reshape(idx.shape)
        dt = tt[1:] - tt[:-1]  # the same subtraction as lay_out's
        m = r1 - r0
        kb = idx.shape[1]
        g = np.asarray(self.x[flat[:(m + 1) * kb]], dtype=float)  # exact: a float gather
        if pad is not None:
            np.copyto(g.reshape(m + 1, kb, -1), 0.0, where=pad[:m + 1, :, None])
        w = np.ascontiguousarray(g.T).reshape(-1, m + 1, kb)  # one array per component
        return Slab(tuple(w), dt[:m], dt[:m] * dt[:m], dt[m] if ahead else None)


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
        tt = np.asarray(rows.t[idx.ravel()], dtype=float).reshape(idx.shape)
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
