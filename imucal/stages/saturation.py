"""Saturated samples: a sensor driven past its range reads flat at its limit.

A clipped axis has no variance, so a saturated stretch can pass the static detector while its
mean is wrong. Blocks holding saturated samples are excluded and reported (method.md §1 gives
no rule; this is what a user of a real product expects).
"""

from __future__ import annotations

import numpy as np

from imucal.numerics.windows import runs_of_true


def saturated_mask(x: np.ndarray, min_run: int = 5) -> np.ndarray:
    """Samples where an axis sits at its extreme value for ``min_run`` or more samples in a row.

    Noise makes an unclipped signal touch its own maximum once or twice; a clipped one sits at
    it. Runs come from :func:`imucal.numerics.windows.runs_of_true`.
    """
    out = np.zeros(len(x), dtype=bool)
    for axis in range(x.shape[1]):
        col = x[:, axis]
        for extreme in (col.max(), col.min()):
            runs = runs_of_true(col == extreme)
            for start, end in runs[(runs[:, 1] - runs[:, 0]) >= min_run]:
                out[start:end] = True  # a loop over clipped runs, not over samples
    return out


def blocks_with(mask: np.ndarray, blocks: np.ndarray) -> np.ndarray:
    """Boolean per block: does it contain any flagged sample? (one cumulative sum)"""
    cs = np.concatenate(([0], np.cumsum(mask)))
    return (cs[blocks[:, 1]] - cs[blocks[:, 0]]) > 0
