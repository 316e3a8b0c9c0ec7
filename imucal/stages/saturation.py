"""Saturated samples: a sensor driven past its range reads flat at its limit.

A clipped axis has no variance, so a saturated stretch can pass the static detector while its
mean is wrong. Blocks holding saturated samples are excluded and reported (method.md §1 gives
no rule; this is what a user of a real product expects).

The signal is read a chunk of rows at a time through row slices (issue 12): the comparisons and
the run edges of one chunk at once, never a mask or a cumulative sum the length of the signal,
unless the caller asks for the mask (:func:`saturated_mask`).
"""

from __future__ import annotations

import numpy as np

CHUNK_ROWS = 1 << 18


def saturated_runs(x, min_run: int = 5, chunk: int = CHUNK_ROWS) -> np.ndarray:
    """(R, 2) sorted, disjoint ``[start, end)`` runs of the samples where an axis sits at its
    extreme value for ``min_run`` or more samples in a row (any axis, either extreme): the
    union of :func:`axis_saturated_runs`."""
    return _union(np.concatenate([np.zeros((0, 2), np.int64),
                                  *axis_saturated_runs(x, min_run, chunk)]))


def axis_saturated_runs(x, min_run: int = 5, chunk: int = CHUNK_ROWS) -> list[np.ndarray]:
    """Per axis ``j``, the runs :func:`saturated_runs` finds in the column ``x[:, j:j+1]``
    alone (sorted, disjoint ``[start, end)``, ``min_run`` samples or more at the column's
    minimum or maximum).

    Noise makes an unclipped signal touch its own maximum once or twice; a clipped one sits at
    it. One pass over ``x``, a chunk of rows at a time (row slices only): each chunk's own
    extremes and where each axis equals them (a few indices, unless clipped), kept while they
    equal the extreme so far (a chunk holding the signal's extreme holds it as its own, so the
    runs at the signal's extremes are all found; a second pass to learn the extremes first
    would read the signal twice). The runs are joined where they meet at a chunk's edge, so a
    run is measured whole before the ``min_run`` test. A NaN in a column makes its extremes
    NaN, as numpy's, and nothing equals them: no runs there."""
    k = int(x.shape[1])
    empty = np.zeros((0, 2), np.int64)
    if len(x) == 0:
        return [empty] * k
    # Per (axis, extreme): the extreme so far (None: none yet; NaN: a NaN seen) and the runs
    # at it.
    best: list = [None] * (2 * k)
    parts: list[list[np.ndarray]] = [[] for _ in range(2 * k)]
    for c0 in range(0, len(x), chunk):
        rows = np.asarray(x[c0:c0 + chunk])
        # Column by column: numpy reduces an (n, 3) array along its rows far slower.
        for e, reduce in enumerate((np.max, np.min)):
            ext = np.array([reduce(rows[:, j]) for j in range(k)], dtype=rows.dtype)
            new = [j for j in range(k) if _at_least(ext[j], best[2 * j + e], e)]
            if not new:
                continue
            at = np.flatnonzero(rows == ext)  # every axis at once: (row, axis) flattened
            row, axis_of = at // k, at % k
            for j in new:
                i = 2 * j + e
                if best[i] is None or ext[j] != best[i]:  # a new extreme: the old runs go
                    best[i], parts[i] = ext[j], []
                parts[i].append(_runs_at(row[axis_of == j]) + c0)
    out = []
    for j in range(k):
        found = [empty]
        for i in (2 * j, 2 * j + 1):
            if best[i] is None or best[i] != best[i]:  # NaN: no runs
                continue
            runs = _union(np.concatenate([empty, *parts[i]]))
            found.append(runs[(runs[:, 1] - runs[:, 0]) >= min_run])
        out.append(_union(np.concatenate(found)))
    return out


def _at_least(v, best, e: int) -> bool:
    """Does a chunk's extreme ``v`` reach the extreme so far (``e`` 0: max, 1: min)? A NaN
    poisons the column for good (numpy's extreme is NaN then)."""
    if best is None:
        return True
    if best != best:
        return False
    if v != v:
        return True  # recorded as the new "extreme": NaN
    return bool(v >= best) if e == 0 else bool(v <= best)


def _runs_at(idx: np.ndarray) -> np.ndarray:
    """[start, end) runs of consecutive sorted indices (``runs_of_true`` of their mask)."""
    if len(idx) == 0:
        return np.zeros((0, 2), np.int64)
    breaks = np.flatnonzero(np.diff(idx) > 1)
    return np.column_stack([idx[np.r_[0, breaks + 1]], idx[np.r_[breaks, len(idx) - 1]] + 1]
                           ).astype(np.int64)


def saturated_mask(x: np.ndarray, min_run: int = 5) -> np.ndarray:
    """(N,) True on the samples of :func:`saturated_runs`."""
    out = np.zeros(len(x), dtype=bool)
    for start, end in saturated_runs(x, min_run):
        out[start:end] = True  # a loop over clipped runs, not over samples
    return out


def _union(runs: np.ndarray) -> np.ndarray:
    """The union of ``[start, end)`` runs as sorted, disjoint runs; runs that touch (one ends
    where the next starts, as at a chunk's edge) are one."""
    runs = np.asarray(runs, np.int64).reshape(-1, 2)
    if len(runs) == 0:
        return runs
    runs = runs[np.argsort(runs[:, 0], kind="stable")]
    ends = np.maximum.accumulate(runs[:, 1])
    new = np.concatenate(([True], runs[1:, 0] > ends[:-1]))
    first = np.flatnonzero(new)
    last = np.concatenate((first[1:] - 1, [len(runs) - 1]))
    return np.column_stack([runs[first, 0], ends[last]])


def blocks_with(mask: np.ndarray, blocks: np.ndarray) -> np.ndarray:
    """Boolean per block: does it contain any flagged sample of ``mask``? (one cumulative sum)"""
    cs = np.concatenate(([0], np.cumsum(mask)))
    return (cs[blocks[:, 1]] - cs[blocks[:, 0]]) > 0


def blocks_meeting(runs: np.ndarray, blocks: np.ndarray) -> np.ndarray:
    """Boolean per block ``[start, end)``: does it hold a sample of the sorted, disjoint
    ``runs`` (:func:`saturated_runs`)? One search per block, no mask of the signal."""
    runs = np.asarray(runs, np.int64).reshape(-1, 2)
    blocks = np.asarray(blocks, np.int64).reshape(-1, 2)
    bad = np.zeros(len(blocks), dtype=bool)
    if len(runs) == 0:
        return bad
    j = np.searchsorted(runs[:, 1], blocks[:, 0], side="right")  # first run ending after start
    ok = (j < len(runs)) & (blocks[:, 1] > blocks[:, 0])
    bad[ok] = runs[j[ok], 0] < blocks[ok, 1]
    return bad
