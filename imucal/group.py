"""Grouping static blocks into segments of steady error conditions (method.md §2).

The literal rule (a jump of the raw still magnitude between consecutive blocks) splits almost
every session, because a sensor whose scales are off by a few percent reads different raw
magnitudes in different poses. What the thesis wants is to notice when the error conditions
change. So the grouping works on calibrated data, by binary segmentation:

1. For a stretch of blocks, find the split that best explains it as two calibrations: the
   boundary ``j`` that minimises the summed cost of fitting M2 to each side on its own.
2. Measure the change at that boundary as the thesis does, on the calibrated still magnitude
   relative to g: one calibration for the whole stretch leaves block errors ``|a|/|g| - 1``
   with some RMS; two calibrations, one per side, leave a smaller one. The part of the misfit
   that the split explains, ``sqrt(rms_one^2 - rms_two^2)``, is the size of the change of
   conditions; above ``delta`` the stretch is split. (Comparing each side's fit on the other
   side's blocks instead amplifies the estimation noise of a 12-block fit past ``delta``.)
3. Repeat on both halves. A side is never left with fewer than ``min_blocks`` blocks, so every
   segment has enough orientations for its 9 parameters.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .accel import jacobian, residuals
from .lm import fit_tikhonov
from .models import ACC_THETA0


@dataclass(frozen=True)
class GroupSettings:
    single_segment: bool = False
    delta: float = 0.01  # thesis code: 0.01 g (its text: 0.02 g), here relative to |g|
    min_blocks: int = 12


@dataclass(frozen=True)
class SplitTest:
    """One tested boundary: where, the change it measured, and whether it split."""

    block: int  # first block of the second part
    change: float  # misfit the split explains: sqrt(rms_one^2 - rms_two^2) of |a|/|g| - 1
    split: bool


@dataclass(frozen=True)
class Grouping:
    segments: list[tuple[int, int]]  # [first block, last block + 1) of each segment
    tests: list[SplitTest]
    mode: str


def group_blocks(means_nominal: np.ndarray, theta_start: np.ndarray, lam: float,
                 settings: GroupSettings = GroupSettings()) -> Grouping:
    """Segments of consecutive blocks calibrated on their own (see the module docstring).

    ``means_nominal`` (B, 3) are the blocks' mean accelerations in the fit's nominal frame and
    ``theta_start`` the whole-session solution, used to start every trial fit.
    """
    n = len(means_nominal)
    if settings.single_segment or n < 2 * settings.min_blocks:
        mode = "single segment (requested)" if settings.single_segment else (
            f"single segment: {n} blocks, fewer than twice the {settings.min_blocks} a segment "
            "needs")
        return Grouping(segments=[(0, n)], tests=[], mode=mode)
    tests: list[SplitTest] = []
    segments = _split(means_nominal, 0, n, theta_start, lam, settings, tests)
    return Grouping(segments=segments, tests=tests, mode="binary segmentation on calibrated "
                    f"still magnitudes (delta {settings.delta:g} of |g|)")


def _fit(pts: np.ndarray, start: np.ndarray, lam: float) -> tuple[np.ndarray, float, float]:
    """Theta, regularised cost and data cost of M3 on the block means ``pts``."""
    rep = fit_tikhonov(lambda th: residuals(th, pts), lambda th: jacobian(th, pts), start,
                       ACC_THETA0, lam)
    return rep.theta, rep.cost, rep.data_cost


def _split(m: np.ndarray, i0: int, i1: int, start: np.ndarray, lam: float,
           settings: GroupSettings, tests: list[SplitTest]) -> list[tuple[int, int]]:
    k = settings.min_blocks
    if i1 - i0 < 2 * k:
        return [(i0, i1)]
    start, _, one = _fit(m[i0:i1], start, lam)
    best = None
    for j in range(i0 + k, i1 - k + 1):
        th_a, c_a, d_a = _fit(m[i0:j], start, lam)
        th_b, c_b, d_b = _fit(m[j:i1], start, lam)
        if best is None or c_a + c_b < best[0]:
            best = (c_a + c_b, j, th_a, th_b, d_a + d_b)
    _, j, th_a, th_b, two = best
    change = float(np.sqrt(max(one - two, 0.0) / (i1 - i0)))
    split = change > settings.delta
    tests.append(SplitTest(block=j, change=change, split=split))
    if not split:
        return [(i0, i1)]
    return (_split(m, i0, j, th_a, lam, settings, tests)
            + _split(m, j, i1, th_b, lam, settings, tests))
