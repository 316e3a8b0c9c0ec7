"""The y ranges the layout gives the magnitude and detector plots: all but the most extreme
samples at each end (one knock or glitch must not squash a plot into a line).

:func:`robust_range` takes the values whole; :class:`RobustRange` takes them a chunk at a time
(issue 12: the magnitudes of a 6-hour 1 kHz session, raw and calibrated, are 350 MB) and gives
the same range to the bit, in the same pass that makes the rows: its quantiles are numpy's
(``np.quantile``, linear method), interpolated as numpy does between the values at the two
ranks around each, and those values are exact, from the few smallest and largest values kept.
:func:`quantiles` finds them in two more passes over the values instead, keeping only a
bracket around each rank (:func:`imucal.numerics.order_stats.ranked_values`): the fallback.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

import numpy as np

from imucal.numerics.order_stats import ranked_values

Chunks = Callable[[], Iterable[np.ndarray]]  # the values, afresh on each call, finite only

# The strided sample that brackets the ranks (order_stats): 8 MB, and its quantiles within
# ~0.1 % of the rank asked for, so the second pass keeps ~1 % of the values at most.
SAMPLE = 1 << 20
PAD = 0.08  # the range is widened by this share of itself at each end


def robust_range(values: np.ndarray, q: float = 0.005, pad: float = PAD
                 ) -> tuple[float, float] | None:
    """A y range that holds all but the ``q`` most extreme finite values at each end, widened
    by ``pad``; None for fewer than two values or a flat signal (the viewer's own range)."""
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    if len(v) < 2:
        return None
    lo, hi = np.quantile(v, [q, 1.0 - q])
    return _padded(lo, hi, pad)


class RobustRange:
    """:func:`robust_range` of values fed a chunk at a time, in one pass: the ``k`` smallest
    and ``k`` largest finite values are kept (exactly; ``k`` from ``n_max``, a bound on how
    many values there will be, is what numpy's quantile at ``q`` and ``1 - q`` reads), so
    the range is numpy's to the bit. Memory: ``2 k`` values, ``q`` of the values at each end
    (0.5 % for the accelerometer's magnitude) and a chunk."""

    def __init__(self, n_max: int, q: float, pad: float = PAD) -> None:
        self.q, self.pad = q, pad
        # numpy reads the values at floor((n - 1) q) and the next (and as far from the top
        # at 1 - q); n <= n_max, and one more for the rounding of (n - 1)(1 - q).
        k = int(np.floor((max(n_max, 1) - 1) * q)) + 3
        self.low, self.high = _Smallest(k), _Smallest(k)
        self.count = 0

    def add(self, v: np.ndarray) -> None:
        v = v[np.isfinite(v)] if not np.isfinite(v).all() else v
        self.count += len(v)
        self.low.add(v)
        self.high.add(-v)  # the largest values, as the smallest of their negatives

    def result(self, chunks: Chunks) -> tuple[float, float] | None:
        """The range; ``chunks`` yields the values again (finite ones only), read only if a
        rank lies outside what was kept (it cannot, for at most ``n_max`` values)."""
        n = self.count
        if n < 2:
            return None
        low, high = self.low.values(), -self.high.values()  # ascending; descending
        q = np.asarray([self.q, 1.0 - self.q], dtype=np.float64)
        virtual = (n - 1) * q  # numpy's linear method: the index in the sorted values
        prev = np.minimum(np.floor(virtual).astype(np.int64), n - 1)
        ranks = np.column_stack([prev, np.minimum(prev + 1, n - 1)])
        got = np.empty(ranks.shape)
        for i, r in np.ndenumerate(ranks):
            if r < len(low):
                got[i] = low[r]
            elif n - 1 - r < len(high):
                got[i] = high[n - 1 - r]
            else:
                return _padded(*quantiles(chunks, n, list(q)), self.pad)
        lo, hi = _lerp(got[:, 0], got[:, 1], virtual - prev)
        return _padded(lo, hi, self.pad)


class _Smallest:
    """The ``k`` smallest of the values fed, exactly (ties included as they come)."""

    def __init__(self, k: int) -> None:
        self.k = k
        self.kept: list[np.ndarray] = []
        self.size = 0
        self.bound = np.inf  # k values <= bound are kept: a larger one is not among them

    def add(self, v: np.ndarray) -> None:
        v = v[v <= self.bound] if self.bound < np.inf else v.copy()
        if len(v):
            self.kept.append(v)
            self.size += len(v)
        if self.size > 2 * self.k + (1 << 16):
            self._shrink()

    def _shrink(self) -> None:
        a = np.concatenate(self.kept) if self.kept else np.zeros(0)
        if len(a) > self.k:
            a.partition(self.k - 1)
            a = a[:self.k].copy()
            self.bound = float(a.max())
        self.kept, self.size = [a], len(a)

    def values(self) -> np.ndarray:
        """The kept values, ascending."""
        self._shrink()
        return np.sort(self.kept[0])


def quantiles(chunks: Chunks, n: int, qs: list[float]) -> list[float]:
    """``np.quantile(values, qs)`` of the ``n`` values ``chunks()`` yields, to the bit, in
    memory bounded by a chunk and a small bracket around each rank (two passes)."""
    q = np.asarray(qs, dtype=np.float64)
    virtual = (n - 1) * q  # numpy's linear method: the index in the sorted values
    prev = np.floor(virtual).astype(np.int64)
    top = virtual >= n - 1  # numpy takes the last value twice there
    prev[top] = n - 1
    nxt = np.minimum(prev + 1, n - 1)
    got = ranked_values(chunks, n, [[int(a), int(b)] for a, b in zip(prev, nxt)], SAMPLE)
    if got is None:  # a bracket missed (ranked_values says when): the values whole, once
        return [float(x) for x in np.quantile(np.concatenate(list(chunks())), q)]
    a = np.array([g[0] for g in got])
    b = np.array([g[-1] for g in got])
    gamma = virtual - prev  # past the last value numpy's differs, but it weighs b - a = 0
    return [float(x) for x in _lerp(a, b, gamma)]


def _lerp(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """numpy's interpolation between the neighbours of a quantile (``_lerp`` in numpy's
    ``_function_base_impl``): from ``a`` below the middle, from ``b`` above it."""
    diff = b - a
    out = a + diff * t
    return np.where(t >= 0.5, b - diff * (1 - t), out)


def _padded(lo: float, hi: float, pad: float) -> tuple[float, float] | None:
    if not hi > lo:
        return None
    return float(lo - pad * (hi - lo)), float(hi + pad * (hi - lo))
