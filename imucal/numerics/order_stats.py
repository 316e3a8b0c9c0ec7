"""Exact order statistics of values given a chunk at a time, in memory bounded by a chunk and a
small bracket (issue 12: a copy of a 6-hour 1 kHz signal is 500 MB).

A first pass takes a strided sample of the values; its quantiles, widened by four standard
deviations of a sample quantile's rank, bracket the ranks asked for. A second pass counts the
values below each bracket and keeps only those inside it; values the sample already holds are
counted, not kept, so a clock's few distinct steps or heavily tied counts cost nothing. The
ranks are then read from the kept values, sorted in place, merged with the counted ones. They
are the values ``np.sort`` puts at those ranks, so an interpolation done on them the way
``np.median`` or ``np.percentile`` does it gives numpy's result to the bit.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

import numpy as np

Chunks = Callable[[], Iterable[np.ndarray]]  # yields 1-D arrays in order, afresh on each call


def ranked_values(chunks: Chunks, n: int, groups: list[list[int]], sample: int
                  ) -> list[list[float]] | None:
    """For each group of (close) ranks, the values at those ranks of the ``n`` values that
    ``chunks()`` yields, sorted; all NaN where a value is NaN (numpy's statistics are NaN then).
    None where a bracket missed (a sample periodic with the values could make it) or the
    brackets hold more than an eighth of the values: the caller then sorts a copy."""
    step = max(1, n // sample)
    drawn = np.concatenate([c[::step].copy() for c in chunks()])  # copies: no chunk is kept
    drawn.sort()
    nan = [[float("nan")] * len(r) for r in groups]
    if len(drawn) and np.isnan(drawn[-1]):
        return nan
    m = len(drawn)
    margin = max(0.004, 4.0 / np.sqrt(max(m, 1)))
    brackets, known, modes = [], [], []
    for ranks in groups:
        lo = int(np.floor((min(ranks) / n - margin) * m))
        hi = int(np.ceil((max(ranks) / n + margin) * m))
        lo_v = drawn[lo] if lo > 0 else -np.inf
        hi_v = drawn[hi] if hi < m else np.inf
        brackets.append((lo_v, hi_v))
        held, times = np.unique(drawn[(drawn >= lo_v) & (drawn <= hi_v)], return_counts=True)
        known.append(held)
        # A value a quarter or more of the bracket's sample equals (a clock's own step):
        # counted by one comparison, and the bracket and the search see only the rest.
        top = int(np.argmax(times)) if len(times) else -1
        modes.append(top if top >= 0 and 4 * times[top] >= times.sum() > 1 else -1)
    del drawn
    counts = [np.zeros(len(k), dtype=np.int64) for k in known]
    below = [0] * len(groups)
    inside: list[list[np.ndarray]] = [[] for _ in groups]
    kept = 0
    for c in chunks():
        if np.isnan(c).any():
            return nan
        for g, (lo_v, hi_v) in enumerate(brackets):
            k, rest = known[g], c
            if modes[g] >= 0:  # inside the bracket, so are the values equal to it
                eq = c == k[modes[g]]
                counts[g][modes[g]] += int(np.count_nonzero(eq))
                rest = c[~eq]
            below[g] += int(np.count_nonzero(rest < lo_v))
            got = rest[(rest >= lo_v) & (rest <= hi_v)]
            if len(k) and len(got):
                pos = np.minimum(np.searchsorted(k, got), len(k) - 1)
                hit = k[pos] == got
                counts[g] += np.bincount(pos[hit], minlength=len(k))
                got = got[~hit]
            inside[g].append(got)
            kept += len(got)
        if kept > n // 8:  # the brackets hold too much: no saving left
            return None
    out = []
    for g, ranks in enumerate(groups):
        picked = values_at_ranks([r - below[g] for r in ranks], known[g], counts[g], inside[g])
        if picked is None:
            return None
        out.append(picked)
    return out


def values_at_ranks(ranks: list[int], known: np.ndarray, counts: np.ndarray,
          inside: list[np.ndarray]) -> list[float] | None:
    """The values at ``ranks`` (within the bracket) of the multiset of ``known`` values (sorted,
    distinct, each ``counts`` times) and the ``inside`` values (none equal to a known one)."""
    rest = np.concatenate(inside) if inside else np.zeros(0)
    rest.sort()
    cum = np.concatenate([[0], np.cumsum(counts)])  # known items before block j: cum[j]
    starts = np.searchsorted(rest, known) + cum[:-1]  # block j's first rank in the merge
    out = []
    for r in ranks:
        if r < 0:
            return None
        j = int(np.searchsorted(starts, r, side="right")) - 1
        if j >= 0 and r < starts[j] + counts[j]:
            out.append(float(known[j]))
            continue
        i = r - int(cum[j + 1])  # every known block up to j ends before rank r
        if i >= len(rest):
            return None
        out.append(float(rest[i]))
    return out
