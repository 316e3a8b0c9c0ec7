"""The y ranges the layout gives the magnitude and detector plots: all but the most extreme
samples at each end (one knock or glitch must not squash a plot into a line).

:func:`robust_range` takes the values whole; :func:`robust_range_of` takes them a chunk at a
time (issue 12: the magnitudes of a 6-hour 1 kHz session, raw and calibrated, are 350 MB), and
gives the same range to the bit: its quantiles are numpy's (``np.quantile``, linear method),
interpolated the way numpy does between the values at the two ranks around each, and those
values are exact order statistics found in bounded memory
(:func:`imucal.numerics.order_stats.ranked_values`).
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


def robust_range_of(chunks: Chunks, finite: Finite, q: float, pad: float = PAD
                    ) -> tuple[float, float] | None:
    """:func:`robust_range` of the values ``chunks()`` yields (finite ones only; ``finite``
    counted them), which are never held together. ``q`` 0 is the values' minimum and maximum
    (``np.quantile``'s 0 and 1), read from ``finite`` without a pass."""
    if finite.count < 2:
        return None
    if q == 0:
        return _padded(finite.min, finite.max, pad)
    lo, hi = quantiles(chunks, finite.count, [q, 1.0 - q])
    return _padded(lo, hi, pad)


def quantiles(chunks: Chunks, n: int, qs: list[float]) -> list[float]:
    """``np.quantile(values, qs)`` of the ``n`` values ``chunks()`` yields, to the bit, in
    memory bounded by a chunk and a small bracket around each rank."""
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


class Finite:
    """How many finite values went by, and their minimum and maximum."""

    def __init__(self) -> None:
        self.count = 0
        self.min, self.max = np.inf, -np.inf

    def add(self, v: np.ndarray) -> np.ndarray:
        """Count the finite values of ``v``; returns them (``v`` itself when all are)."""
        ok = np.isfinite(v)
        if not ok.all():
            v = v[ok]
        if len(v):
            self.count += len(v)
            self.min = min(self.min, float(v.min()))
            self.max = max(self.max, float(v.max()))
        return v
