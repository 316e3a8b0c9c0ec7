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

from imucal.numerics.rows import column_extremes

CHUNK_ROWS = 1 << 18


def saturated_runs(x, min_run: int = 5, chunk: int = CHUNK_ROWS) -> np.ndarray:
    """(R, 2) sorted, disjoint ``[start, end)`` runs of the samples where an axis sits at its
    extreme value for ``min_run`` or more samples in a row (any axis, either extreme).

    Noise makes an unclipped signal touch its own maximum once or twice; a clipped one sits at
    it. Two passes over ``x``, a chunk of rows at a time (row slices only): its extremes, then
    where each axis equals them (a few indices, unless clipped), cut into runs and joined where
    they meet at a chunk's edge, so a run is measured whole before the ``min_run`` test.
    """
    k = int(x.shape[1])
    empty = np.zeros((0, 2), np.int64)
    if len(x) == 0:
        return empty
    lo, hi = column_extremes(x, chunk)
    parts: list[list[np.ndarray]] = [[empty] for _ in range(2 * k)]
    for c0 in range(0, len(x), chunk):
        rows = np.asarray(x[c0:c0 + chunk])
        for e, extreme in enumerate((hi, lo)):
            at = np.flatnonzero(rows == extreme)  # every axis at once: (row, axis) flattened
            row, axis_of = at // k, at % k
            for axis in range(k):
                parts[2 * axis + e].append(_runs_at(row[axis_of == axis]) + c0)
    found = [empty]
    for p in parts:
        runs = _union(np.concatenate(p))
        found.append(runs[(runs[:, 1] - runs[:, 0]) >= min_run])
    return _union(np.concatenate(found))


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
