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
3. Repeat on both halves. A side is never left with fewer than ``min_blocks`` blocks or fewer
   than 9 distinct orientations, so every segment can determine its 9 parameters.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from imucal.models import ACC_THETA0
from imucal.numerics.directions import distinct_orientations
from imucal.numerics.least_squares import fit_tikhonov
from imucal.settings import GroupSettings, Settings
from imucal.stages.accel import jacobian, residuals


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
                 settings: GroupSettings = Settings().group) -> Grouping:
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
    j, th_a, th_b, two = best_split(m[i0:i1], start, lam, k)
    j += i0
    change = float(np.sqrt(max(one - two, 0.0) / (i1 - i0)))
    split = change > settings.delta
    # Never leave a side with too few orientations for its 9 parameters (method.md §2).
    if split and min(distinct_orientations(m[i0:j]), distinct_orientations(m[j:i1])) < 9:
        split = False
    tests.append(SplitTest(block=j, change=change, split=split))
    if not split:
        return [(i0, i1)]
    return (_split(m, i0, j, th_a, lam, settings, tests)
            + _split(m, j, i1, th_b, lam, settings, tests))


def best_split(m: np.ndarray, start: np.ndarray, lam: float, k: int
               ) -> tuple[int, np.ndarray, np.ndarray, float]:
    """The boundary ``j`` (``k <= j <= n - k``) minimising the summed regularised cost of
    fitting ``m[:j]`` and ``m[j:]`` on their own, each fit started from ``start``.

    Returns ``j``, the two sides' solutions and their summed data cost. The exact search fits
    both sides for every ``j`` (``O(n)`` fits of ``O(n)`` points each). Here every ``j`` is
    first scored by the Gauss-Newton model of both fits at ``start``: with the residuals ``r``
    and Jacobian ``J`` of each block at ``start`` the minimum of
    ``|r_S + J_S d|^2 + lam |start + d - theta_0|^2`` over ``d`` is
    ``c_S - g_S' A_S^-1 g_S`` with ``A_S = J_S'J_S + lam I``, ``g_S = J_S' r_S + lam e`` and
    ``c_S = |r_S|^2 + lam |e|^2`` (``e = start - theta_0``), and every sum over a side is a
    difference of cumulative sums, so all ``j`` cost ``O(n)`` together. Then the exact fits
    are run in the order of that score, until no remaining ``j`` can beat the best exact cost
    unless the model errs there by more than three times the largest error seen so far. The
    fits are the exact search's (same data, same start; ties go to the smaller ``j``), so the
    answer is the exact search's whenever the model's error stays within that margin;
    ``bench/check_group.py`` compares the two on random sessions. A handful of fits instead
    of ``2 n``: the grouping is linear in the number of blocks.
    """
    n = len(m)
    js = np.arange(k, n - k + 1)
    approx = _gauss_newton_split_costs(m, start, lam, js)
    if approx is None:  # the model is singular or not finite: every boundary exactly
        order = np.arange(len(js))
        approx = np.zeros(len(js))
        exhaustive = True
    else:
        order = np.argsort(approx, kind="stable")
        exhaustive = False
    exact: dict[int, tuple[float, np.ndarray, np.ndarray, float]] = {}
    best_cost = np.inf
    err = 0.0
    for count, i in enumerate(order):
        if not exhaustive and count >= 3 and approx[i] - 3.0 * err > best_cost:
            break
        j = int(js[i])
        th_a, c_a, d_a = _fit(m[:j], start, lam)
        th_b, c_b, d_b = _fit(m[j:], start, lam)
        exact[j] = (c_a + c_b, th_a, th_b, d_a + d_b)
        best_cost = min(best_cost, c_a + c_b)
        if not exhaustive:
            err = max(err, abs(c_a + c_b - approx[i]))
    j = min(exact, key=lambda jj: (exact[jj][0], jj))
    _, th_a, th_b, two = exact[j]
    return j, th_a, th_b, two


def _gauss_newton_split_costs(m: np.ndarray, start: np.ndarray, lam: float, js: np.ndarray
                              ) -> np.ndarray | None:
    """The Gauss-Newton model of the summed fit costs of ``m[:j]`` and ``m[j:]`` (see
    :func:`best_split`) for every ``j`` in ``js``; ``None`` where it is not usable."""
    r = residuals(start, m)
    J = jacobian(start, m)
    p = J.shape[1]
    e = start - ACC_THETA0
    zero = np.zeros((1, p))
    cJJ = np.concatenate([np.zeros((1, p, p)), np.cumsum(J[:, :, None] * J[:, None, :], 0)])
    cJr = np.concatenate([zero, np.cumsum(J * r[:, None], 0)])
    crr = np.concatenate([[0.0], np.cumsum(r * r)])
    n = len(m)
    reg = lam * np.eye(p)
    with np.errstate(all="ignore"):
        try:
            total = np.zeros(len(js))
            for a, b in ((np.zeros_like(js), js), (js, np.full_like(js, n))):
                A = cJJ[b] - cJJ[a] + reg
                g = cJr[b] - cJr[a] + lam * e
                x = np.linalg.solve(A, g[..., None])[..., 0]
                total += crr[b] - crr[a] + lam * float(e @ e) - np.einsum("bi,bi->b", g, x)
        except np.linalg.LinAlgError:
            return None
    return total if np.all(np.isfinite(total)) else None
