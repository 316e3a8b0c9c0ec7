"""A bucket's samples and step times gathered a slab of rows at a time, on request (method.md
M5; issue 12): what a bucket keeps is each interval's first sample and step count, so the
arrays laid out time-major (:mod:`.buckets`) never exist whole, only the slab being integrated.

Every slab holds the same values, to the bit, as the same rows of :func:`.buckets.lay_out`'s
arrays (the same gathers and the same elementwise arithmetic), so whatever is computed from a
slab is unchanged.
"""

from __future__ import annotations

import numpy as np

from imucal.numerics.rk4.buckets import Bucket


def _rows(key: slice, n: int) -> tuple[int, int]:
    if not isinstance(key, slice):
        raise TypeError("lazily gathered rows are read by slices of rows")
    r0, r1, step = key.indices(n)
    if step != 1:
        raise TypeError("lazily gathered rows are read by contiguous slices")
    return r0, max(r1, r0)


def _sample_index(starts: np.ndarray, n_steps: np.ndarray, last: int, r0: int, r1: int
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Rows ``r0 .. r1 - 1`` of :func:`.buckets.lay_out`'s ``i0`` and ``valid``."""
    j = np.arange(r0, r1)[:, None]
    valid = j <= n_steps[None, :]
    return np.where(valid, np.minimum(starts[None, :] + j, last), 0), valid


class LazySamples:
    """One component of a bucket's samples ((L + 1, K_b), zero in the padding), read by slices
    of rows: ``x[r0:r1]`` gathers those rows from the column ``c`` (a view of the session's
    array, not a copy), as float64."""

    def __init__(self, c: np.ndarray, starts: np.ndarray, n_steps: np.ndarray, last: int,
                 length: int):
        self.c, self.starts, self.n_steps, self.last = c, starts, n_steps, last
        self.shape = (length + 1, len(starts))
        self.size = self.shape[0] * self.shape[1]

    def __getitem__(self, key: slice) -> np.ndarray:
        r0, r1 = _rows(key, self.shape[0])
        i0, valid = _sample_index(self.starts, self.n_steps, self.last, r0, r1)
        out = np.asarray(self.c[i0], dtype=float)  # exact: = the float column's gather
        out[~valid] = 0.0
        return out


class LazySteps:
    """A bucket's step times ``dt`` ((L, K_b), 0 for padding), or ``dt^2``, read by slices of
    rows, from the timestamps ``t``."""

    def __init__(self, t: np.ndarray, starts: np.ndarray, n_steps: np.ndarray, length: int,
                 squared: bool = False):
        self.t, self.starts, self.n_steps, self.squared = t, starts, n_steps, squared
        self.shape = (length, len(starts))
        self.size = self.shape[0] * self.shape[1]

    def __getitem__(self, key: slice) -> np.ndarray:
        r0, r1 = _rows(key, self.shape[0])
        i0, valid = _sample_index(self.starts, self.n_steps, len(self.t) - 1, r0, r1 + 1)
        dt = np.where(valid[1:], self.t[i0[1:]] - self.t[i0[:-1]], 0.0)
        return dt * dt if self.squared else dt


def lay_out_lazy(t: np.ndarray, starts: np.ndarray, n_steps: np.ndarray, idx: np.ndarray
                 ) -> Bucket:
    """:func:`.buckets.lay_out` without its arrays: ``i0`` and ``valid`` are None, ``dt`` and
    ``dt2`` are :class:`LazySteps` (the samples: :func:`lazy_samples`)."""
    L = int(max(n_steps[idx].max(), 1))
    s, n = starts[idx], n_steps[idx]
    return Bucket(idx, None, None, LazySteps(t, s, n, L), LazySteps(t, s, n, L, squared=True))


def lazy_samples(bucket: Bucket, comps: list[np.ndarray], last: int) -> tuple:
    """The samples of a :func:`lay_out_lazy` bucket, one :class:`LazySamples` per component;
    ``last`` is the last sample index (``len(t) - 1``)."""
    dt = bucket.dt
    return tuple(LazySamples(c, dt.starts, dt.n_steps, last, dt.shape[0]) for c in comps)
