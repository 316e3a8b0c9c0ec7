"""Saturated samples: a sensor driven past its range reads flat at its limit.

A clipped axis has no variance, so a saturated stretch can pass the static detector while its
mean is wrong. Blocks holding saturated samples are excluded and reported (method.md §1 gives
no rule; this is what a user of a real product expects).
"""

from __future__ import annotations

import numpy as np


def saturated_mask(x: np.ndarray, min_run: int = 5) -> np.ndarray:
    """Samples where an axis sits at its extreme value for ``min_run`` or more samples in a row.

    Noise makes an unclipped signal touch its own maximum once or twice; a clipped one sits at
    it. Vectorised: run lengths from the edges of a boolean array.
    """
    out = np.zeros(len(x), dtype=bool)
    for axis in range(x.shape[1]):
        col = x[:, axis]
        for extreme in (col.max(), col.min()):
            at = col == extreme
            if at.sum() < min_run:
                continue
            padded = np.concatenate(([False], at, [False])).astype(np.int8)
            edges = np.flatnonzero(np.diff(padded)).reshape(-1, 2)
            long_runs = edges[(edges[:, 1] - edges[:, 0]) >= min_run]
            if len(long_runs):
                d = np.zeros(len(col) + 1, dtype=np.int32)
                np.add.at(d, long_runs[:, 0], 1)
                np.add.at(d, long_runs[:, 1], -1)
                out |= np.cumsum(d[:-1]) > 0
    return out


def blocks_with(mask: np.ndarray, blocks: np.ndarray) -> np.ndarray:
    """Boolean per block: does it contain any flagged sample? (one cumulative sum)"""
    cs = np.concatenate(([0], np.cumsum(mask)))
    return (cs[blocks[:, 1]] - cs[blocks[:, 0]]) > 0
