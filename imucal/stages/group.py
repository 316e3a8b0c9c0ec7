"""Grouping static blocks into segments of steady error conditions (method.md §2).

The literal rule (a jump of the raw still magnitude between consecutive blocks) splits almost
every session, because a sensor whose scales are off by a few percent reads different raw
magnitudes in different poses; and a fixed threshold in g cannot know how noisy the blocks
are. What the thesis wants is to notice when the error conditions change. So the grouping
works on calibrated data, by binary segmentation:

1. For a stretch of ``n`` blocks, find the split that best explains it as two calibrations:
   the boundary ``j`` that minimises the summed cost of fitting M2 by M3 to each side on its
   own (block means, one residual per block, the Tikhonov prior centred on the stretch's
   own calibration so that it pulls toward "no change", not toward nominal). Only
   boundaries that leave each side ``min_blocks`` blocks and 9 distinct orientations are
   tried, so every segment can determine its 9 parameters (the rest is merged into its
   neighbour, and the test says so).
2. Decide by an F-test whether the split explains more than the noise does: with ``RSS_1``
   the residual sum of squares of one fit and ``RSS_2`` that of the two fits,
   ``F = ((RSS_1 - RSS_2) / 9) / (RSS_2 / (n - 18))``, F(9, n - 18) distributed for a
   steady stretch (the Chow test). Each block's residual is weighted by the inverse of its
   noise variance, propagated from the scatter of its own samples (``sigma_k^2 / n_k`` per
   axis): a noisy block counts for less. The noise's *scale* is taken from ``RSS_2``, not from
   the scatter, because real block means scatter more than white noise predicts (slow drift,
   filtered or correlated samples: the two-fit residual variance on the imu_tk Xsens
   recording is 7.4 times the scatter's prediction), and a test trusting the scatter there
   would split it (its best split gains 316 times a block's predicted variance, against a
   chi-square(9) threshold of 34). The best of ``J`` boundaries is the largest of ``J``
   statistics, so its p-value is multiplied by ``J`` (Bonferroni, conservative since
   neighbouring boundaries are alike); the stretch is split where that is below
   ``split_alpha``.
   An explicit ``delta`` replaces the test by the older rule on the size of the change (the
   part of the calibrated still magnitude's misfit, relative to g, that the split explains).
3. Repeat on both halves.

Every tested stretch is recorded (:class:`SplitTest`): its statistic, threshold, p-value,
decision and why.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from imucal.errors import ImucalError
from imucal.models import ACC_THETA0, acc_T
from imucal.numerics.directions import distinct_orientations
from imucal.numerics.least_squares import fit_tikhonov
from imucal.numerics.windows import centred_segment_sums
from imucal.settings import GroupSettings, Settings
from imucal.stages.accel import jacobian, residuals

N_PARAMS = 9  # parameters of M2 each segment fits
MIN_ORIENTATIONS = 9  # distinct orientations a segment needs for them
ORIENTATION_ANGLE_DEG = 15.0  # as distinct_orientations counts them


@dataclass(frozen=True)
class SplitTest:
    """One tested stretch of blocks ``[start, end)``: its best boundary, the F-test of one
    calibration against two there, and the decision."""

    start: int
    end: int
    block: int | None  # best boundary (first block of the second part); None: none allowed
    boundaries: int  # boundaries tried (the Bonferroni factor)
    change: float  # misfit the split explains: sqrt(rms_one^2 - rms_two^2) of |a|/|g| - 1
    f: float  # F statistic of the best boundary
    dof: tuple[int, int]  # (9, n - 18)
    p_value: float  # P(F > f) at that boundary alone
    p_adjusted: float  # times the boundaries tried, at most 1
    f_critical: float  # the F at which p_adjusted equals split_alpha
    noise_ratio: float  # two-fit residual variance over what the blocks' scatter predicts
    split: bool
    reason: str


@dataclass(frozen=True)
class Grouping:
    segments: list[tuple[int, int]]  # [first block, last block + 1) of each segment
    tests: list[SplitTest]
    mode: str
    alpha: float  # significance level of the split test
    delta: float | None  # the explicit change threshold that replaced the test, if given


def block_mean_variance(acc: np.ndarray, blocks: np.ndarray) -> np.ndarray:
    """Per-axis variance of each block's mean, ``s_k^2 / n_k`` from the block's own scatter
    (B, 3). Centred on the first sample and summed per block, so it keeps its digits."""
    n = (blocks[:, 1] - blocks[:, 0]).astype(float)
    # Run by run, not a centred copy of the signal (= np.asarray(acc, float) - acc[0]).
    s1, s2 = centred_segment_sums(acc, blocks[:, 0], blocks[:, 1], np.asarray(acc[0], float))
    m1, m2 = s1 / n[:, None], s2 / n[:, None]
    return np.clip(m2 - m1 * m1, 0, None) / np.maximum(n - 1, 1)[:, None]


def group_blocks(means_nominal: np.ndarray, mean_var_nominal: np.ndarray,
                 theta_start: np.ndarray, lam: float,
                 settings: GroupSettings = Settings().group) -> Grouping:
    """Segments of consecutive blocks calibrated on their own (see the module docstring).

    ``means_nominal`` (B, 3) are the blocks' mean accelerations in the fit's nominal frame,
    ``mean_var_nominal`` (B, 3) the per-axis variance of each mean in that frame
    (:func:`block_mean_variance` over the nominal scale squared) and ``theta_start`` the
    whole-session solution, used to start every trial fit.
    """
    n = len(means_nominal)
    alpha, delta = settings.alpha, settings.delta
    if not 0.0 < alpha < 1.0:
        raise ImucalError(f"split_alpha must be a fraction between 0 and 1, got {alpha!r}",
                          source="settings", field="split_alpha")
    if delta is not None and not delta > 0.0:
        raise ImucalError(f"delta must be a number > 0 or None (decide by the test), got "
                          f"{delta!r}", source="settings", field="delta")
    if settings.single_segment or n < 2 * settings.min_blocks:
        mode = "single segment (requested)" if settings.single_segment else (
            f"single segment: {n} blocks, fewer than twice the {settings.min_blocks} a segment "
            "needs")
        return Grouping(segments=[(0, n)], tests=[], mode=mode, alpha=alpha, delta=delta)
    w, scale = block_weights(means_nominal, mean_var_nominal, theta_start)
    data = _Data(means_nominal, w, scale, lam, settings)
    tests: list[SplitTest] = []
    segments = _split(data, 0, n, theta_start, tests)
    rule = (f"a change above delta {delta:g} of |g|" if delta is not None else
            f"F-test of one fit against two, alpha {alpha:g} after Bonferroni over the "
            "boundaries tried")
    return Grouping(segments=segments, tests=tests, alpha=alpha, delta=delta,
                    mode=f"binary segmentation on calibrated block means: {rule}")


def block_weights(m: np.ndarray, var: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, float]:
    """Weights ``w_k`` of the block residuals ``r_k = 1 - |T K (m_k - b)|`` (M3), and the
    factor turning a weighted sum of squares into units of the blocks' predicted noise.

    The variance of ``r_k`` is ``sum_i (d r_k / d m_i)^2 var_i``; ``w_k^2`` is its inverse
    normalised to mean 1, so lambda weighs against the data as it did unweighted. A block with
    no scatter (a constant signal) gets the median variance, and none is trusted below a
    hundredth of it: one quantised block may not outweigh the rest.
    """
    M = acc_T(theta) * theta[3:6]
    y = (m - theta[6:9]) @ M.T
    grad = (y / np.linalg.norm(y, axis=1, keepdims=True)) @ M
    v = np.einsum("bi,bi->b", grad * grad, var)
    good = np.isfinite(v) & (v > 0)
    if not good.any():
        return np.ones(len(m)), float("nan")
    med = float(np.median(v[good]))
    v = np.where(good, np.maximum(v, 0.01 * med), med)
    inv = 1.0 / v
    scale = float(inv.mean())
    return np.sqrt(inv / scale), scale


@dataclass(frozen=True)
class _Data:
    m: np.ndarray  # block means, nominal frame
    w: np.ndarray  # their residuals' weights
    scale: float  # weighted sum of squares -> units of the predicted noise
    lam: float
    settings: GroupSettings


def _fit(pts: np.ndarray, w: np.ndarray, start: np.ndarray, lam: float,
         centre: np.ndarray = ACC_THETA0) -> tuple[np.ndarray, float, float]:
    """Theta, regularised cost and weighted data cost of M3 on the block means ``pts``, the
    Tikhonov prior centred on ``centre``."""
    rep = fit_tikhonov(lambda th: w * residuals(th, pts),
                       lambda th: w[:, None] * jacobian(th, pts), start, centre, lam)
    return rep.theta, rep.cost, rep.data_cost


def _split(d: _Data, i0: int, i1: int, start: np.ndarray, tests: list[SplitTest]
           ) -> list[tuple[int, int]]:
    k = d.settings.min_blocks
    if i1 - i0 < 2 * k:
        return [(i0, i1)]
    m, w = d.m[i0:i1], d.w[i0:i1]
    # The stretch's own calibration (M3, prior at the nominal theta_0). The test then fits one
    # calibration and two with the prior centred on it: a prior at theta_0 would pull each
    # half (half the data) harder than the whole, and on a steady session leave two fits
    # with a larger residual than one. Centred here it pulls toward "no change" only, and
    # still holds any direction a half leaves undetermined.
    start, _, _ = _fit(m, w, start, d.lam)
    th_one, _, one = _fit(m, w, start, d.lam, centre=start)
    js, excluded = split_candidates(m - start[6:9], k)
    if len(js) == 0:
        tests.append(_untested(i0, i1, f"merged: no boundary leaves both sides {k} blocks and "
                               f"{MIN_ORIENTATIONS} distinct orientations"))
        return [(i0, i1)]
    j, th_a, th_b, two = best_split(m, w, start, d.lam, js)
    test = _decide(d, i0, i1, j, (th_one, th_a, th_b), one, two, len(js))
    if excluded:
        test = _with_reason(test, f"{test.reason}; {_boundaries(excluded)} not tried: a side "
                            f"would have fewer than {MIN_ORIENTATIONS} orientations")
    tests.append(test)
    if not test.split:
        return [(i0, i1)]
    j += i0
    return _split(d, i0, j, th_a, tests) + _split(d, j, i1, th_b, tests)


def _decide(d: _Data, i0: int, i1: int, j: int, thetas: tuple[np.ndarray, ...], one: float,
            two: float, n_js: int) -> SplitTest:
    """The F-test (or the explicit delta) at boundary ``j`` of the stretch ``[i0, i1)``."""
    m = d.m[i0:i1]
    n = i1 - i0
    th_one, th_a, th_b = thetas
    r1 = residuals(th_one, m)
    r2 = np.r_[residuals(th_a, m[:j]), residuals(th_b, m[j:])]
    change = float(np.sqrt(max(np.mean(r1 * r1) - np.mean(r2 * r2), 0.0)))
    dof = (N_PARAMS, n - 2 * N_PARAMS)
    alpha = d.settings.alpha
    if dof[1] < 1:
        return _untested(i0, i1, f"kept: {n} blocks leave no degree of freedom for the test "
                         f"of 2 x {N_PARAMS} parameters", block=i0 + j, boundaries=n_js,
                         change=change)
    # imported here, where a boundary is tested: scipy.special costs ~0.1 s CPU to import
    from scipy.special import fdtrc, fdtri

    gain = max(one - two, 0.0)
    f = (gain / dof[0]) / (two / dof[1]) if two > 0 else float("inf")
    p = float(fdtrc(*dof, f))  # P(F > f), the F distribution's tail
    p_adj = min(1.0, p * n_js)
    f_crit = float(fdtri(*dof, 1.0 - alpha / n_js))  # F exceeded with probability alpha/n_js
    noise_ratio = d.scale * two / dof[1]
    if d.settings.delta is not None:
        split = change > d.settings.delta
        why = f"change {change:.3g} {'>' if split else '<='} delta {d.settings.delta:g}"
    else:
        split = p_adj < alpha
        why = (f"F {f:.3g} {'>' if split else '<='} {f_crit:.3g} (p {p_adj:.2g} after "
               f"Bonferroni over {_boundaries(n_js)}, alpha {alpha:g})")
    if split:
        orient = (distinct_orientations(m[:j] - th_a[6:9]),
                  distinct_orientations(m[j:] - th_b[6:9]))
        if min(orient) < MIN_ORIENTATIONS:
            split = False
            why = (f"merged: {why}, but the sides would have {orient[0]} and {orient[1]} "
                   f"distinct orientations (a segment needs {MIN_ORIENTATIONS})")
        else:
            why = f"split: {why}"
    else:
        why = f"kept: {why}"
    return SplitTest(start=i0, end=i1, block=i0 + j, boundaries=n_js, change=change, f=f,
                     dof=dof, p_value=p, p_adjusted=p_adj, f_critical=f_crit,
                     noise_ratio=noise_ratio, split=split, reason=why)


def _untested(i0: int, i1: int, reason: str, block: int | None = None, boundaries: int = 0,
              change: float = float("nan")) -> SplitTest:
    nan = float("nan")
    return SplitTest(start=i0, end=i1, block=block, boundaries=boundaries, change=change, f=nan,
                     dof=(N_PARAMS, i1 - i0 - 2 * N_PARAMS), p_value=nan, p_adjusted=nan,
                     f_critical=nan, noise_ratio=nan, split=False, reason=reason)


def _boundaries(n: int) -> str:
    return f"{n} boundary" if n == 1 else f"{n} boundaries"


def _with_reason(t: SplitTest, reason: str) -> SplitTest:
    return dataclasses.replace(t, reason=reason)


def split_candidates(v: np.ndarray, k: int) -> tuple[np.ndarray, int]:
    """Boundaries ``j`` (``k <= j <= n - k``) that leave ``v[:j]`` and ``v[j:]`` at least
    :data:`MIN_ORIENTATIONS` distinct directions each, and how many others were left out.

    The counts are the greedy ones of ``distinct_orientations``, kept for every prefix (and,
    scanning from the end, every suffix) in one pass each: linear in the number of blocks.
    """
    n = len(v)
    js = np.arange(k, n - k + 1)
    if len(js) == 0:
        return js, 0
    pre = _running_orientations(v)  # pre[i]: directions in v[:i + 1]
    suf = _running_orientations(v[::-1])[::-1]  # suf[i]: directions in v[i:]
    ok = (pre[js - 1] >= MIN_ORIENTATIONS) & (suf[js] >= MIN_ORIENTATIONS)
    return js[ok], int((~ok).sum())


def _running_orientations(v: np.ndarray) -> np.ndarray:
    u = v / np.linalg.norm(v, axis=1, keepdims=True)
    cos_min = np.cos(np.radians(ORIENTATION_ANGLE_DEG))
    kept = np.empty_like(u)
    counts = np.empty(len(u), dtype=np.int64)
    nk = 0
    for i, x in enumerate(u):  # one step per block (tens to hundreds), not per sample
        if nk == 0 or np.max(kept[:nk] @ x) < cos_min:
            kept[nk] = x
            nk += 1
        counts[i] = nk
    return counts


def best_split(m: np.ndarray, w: np.ndarray, start: np.ndarray, lam: float, js: np.ndarray
               ) -> tuple[int, np.ndarray, np.ndarray, float]:
    """The boundary ``j`` in ``js`` minimising the summed regularised cost of fitting ``m[:j]``
    and ``m[j:]`` (residuals weighted by ``w``) on their own, each fit started from ``start``
    with its Tikhonov prior centred on ``start`` (the one calibration of the whole stretch).

    Returns ``j``, the two sides' solutions and their summed data cost. The exact search fits
    both sides for every ``j`` (``O(n)`` fits of ``O(n)`` points each). Here every ``j`` is
    first scored by the Gauss-Newton model of both fits at ``start``: with the residuals ``r``
    and Jacobian ``J`` of each block at ``start`` the minimum of
    ``|r_S + J_S d|^2 + lam |d|^2`` over ``d`` is ``c_S - g_S' A_S^-1 g_S`` with
    ``A_S = J_S'J_S + lam I``, ``g_S = J_S' r_S`` and ``c_S = |r_S|^2``, and every sum over a
    side is a difference of cumulative sums, so all ``j`` cost ``O(n)`` together. Then the
    exact fits are run in the order of that score, until no remaining ``j`` can beat the best
    exact cost unless the model errs there by more than three times the largest error seen so
    far. The fits are the exact search's (same data, same start; ties go to the smaller
    ``j``), so the answer is the exact search's whenever the model's error stays within that
    margin; ``bench/check_group.py`` compares the two on random sessions. A handful of fits
    instead of ``2 n``: the grouping is linear in the number of blocks.
    """
    js = np.asarray(js)
    approx = _gauss_newton_split_costs(m, w, start, lam, js)
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
        th_a, c_a, d_a = _fit(m[:j], w[:j], start, lam, centre=start)
        th_b, c_b, d_b = _fit(m[j:], w[j:], start, lam, centre=start)
        exact[j] = (c_a + c_b, th_a, th_b, d_a + d_b)
        best_cost = min(best_cost, c_a + c_b)
        if not exhaustive:
            err = max(err, abs(c_a + c_b - approx[i]))
    j = min(exact, key=lambda jj: (exact[jj][0], jj))
    _, th_a, th_b, two = exact[j]
    return j, th_a, th_b, two


def _gauss_newton_split_costs(m: np.ndarray, w: np.ndarray, start: np.ndarray, lam: float,
                              js: np.ndarray) -> np.ndarray | None:
    """The Gauss-Newton model of the summed fit costs of ``m[:j]`` and ``m[j:]`` (see
    :func:`best_split`) for every ``j`` in ``js``; ``None`` where it is not usable."""
    r = w * residuals(start, m)
    J = w[:, None] * jacobian(start, m)
    p = J.shape[1]
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
                g = cJr[b] - cJr[a]
                x = np.linalg.solve(A, g[..., None])[..., 0]
                total += crr[b] - crr[a] - np.einsum("bi,bi->b", g, x)
        except np.linalg.LinAlgError:
            return None
    return total if np.all(np.isfinite(total)) else None
