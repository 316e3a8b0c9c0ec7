"""Standard errors of a least-squares fit whose residuals are correlated in sequence.

``s^2 (J'J)^-1`` holds for independent residuals. A residual that varies slowly along the
sequence (a field that changes along a hand's path) makes neighbouring rows repeat each other,
and that formula then counts far more independent rows than there are. Here:

- the delete-a-block jackknife (Künsch 1989) over contiguous blocks whose length follows the
  residuals' own autocorrelation (Sokal's automatic window for the integrated autocorrelation
  time), each deleted block's refit taken as one Gauss-Newton step from the full fit (the
  linearised jackknife with the leave-out normal matrix, so that a block which alone holds
  some direction's information counts as much as it does);
- its mean generalised design effect ``tr(C_white^-1 C_jack) / p`` (Rao and Scott's first-order
  correction), by which the white covariance is scaled: the jackknife alone is as noisy as a
  sandwich (on white synthetic sessions its standard errors scattered 0.75-1.56 of the white
  ones), the mean over the ``p`` parameters' directions is not (0.93-1.12), and on four real
  recordings the scaled covariance judged the halves' differences as well as the jackknife's
  own (bench/mag_se.md).
"""

from __future__ import annotations

import numpy as np

# Sokal's window: the smallest lag W with W >= WINDOW_C * tau(W), tau(W) = 1 + 2 sum_1^W rho;
# 5 is the usual choice for an exponential decay; these residuals' autocorrelation has a long,
# slow tail (a field along a path: 0.06-0.14 at 1.75 s on BROAD), and 8 reaches it (measured on
# four real recordings, bench/mag_se.md).
WINDOW_C = 8.0
# At least this many blocks: fewer make the variance estimate itself too noisy (9 degrees of
# freedom: its square root within +-25 %). Longer correlation than n / MIN_BLOCKS is cut to it.
MIN_BLOCKS = 10


def correlation_window(r: np.ndarray, c: float = WINDOW_C) -> tuple[int, float]:
    """Sokal's automatic window ``W`` (rows) of the sequence ``r`` and its integrated
    autocorrelation time ``tau(W)`` (rows; 1 for independent rows). The autocorrelation by
    FFT (n log n)."""
    r = np.asarray(r, float) - np.mean(r)
    n = len(r)
    f = np.fft.rfft(r, 2 * n)
    acf = np.fft.irfft(f * np.conj(f))[:n]
    if not acf[0] > 0:
        return 1, 1.0
    tau = 2.0 * np.cumsum(acf / acf[0]) - 1.0
    ok = np.arange(n) >= c * tau
    w = int(np.argmax(ok)) if ok.any() else n - 1
    return max(w, 1), float(tau[w])


def block_jackknife_cov(J: np.ndarray, r: np.ndarray, block: int | None = None
                        ) -> tuple[np.ndarray, int]:
    """The covariance of the least-squares parameters (``J`` (n, p) the residuals' Jacobian and
    ``r`` (n,) the residuals at the solution, rows in sequence order) by the delete-a-block
    jackknife, and the block length used (rows; :func:`correlation_window` unless given).
    Block ``k`` left out moves the solution by ``(J'J - J_k'J_k)^-1 J_k' r_k`` (one
    Gauss-Newton step: ``J'r = 0`` at the solution); the covariance is ``(K - 1) / K`` times
    the sum of the moves' outer products about their mean. Linear in n for the blocks."""
    J, r = np.asarray(J, float), np.asarray(r, float)
    n, p = J.shape
    if block is None:
        block = correlation_window(r)[0]
    block = int(max(1, min(block, n // MIN_BLOCKS)))
    K = max(n // block, 2)
    cut = block * (K - 1)  # the last block takes the remainder
    Jr = J * r[:, None]
    S = np.vstack([Jr[:cut].reshape(K - 1, block, p).sum(axis=1), Jr[cut:].sum(axis=0)])
    Jb = J[:cut].reshape(K - 1, block, p)
    Nk = np.concatenate([np.matmul(Jb.transpose(0, 2, 1), Jb), (J[cut:].T @ J[cut:])[None]])
    # columns scaled to unit norm first, as the full normal matrix's inverse elsewhere
    d = 1.0 / np.maximum(np.linalg.norm(J, axis=0), 1e-300)
    N = (J * d).T @ (J * d)
    left = N[None] - Nk * np.outer(d, d)
    try:
        move = np.linalg.solve(left, (S * d)[:, :, None])[:, :, 0] * d
    except np.linalg.LinAlgError:  # a block without which a direction is not determined
        move = np.matmul(np.linalg.pinv(left), (S * d)[:, :, None])[:, :, 0] * d
    move -= move.mean(axis=0)
    return (K - 1) / K * move.T @ move, block


def design_effect_cov(J: np.ndarray, r: np.ndarray, dof: int
                      ) -> tuple[np.ndarray, np.ndarray, float, int]:
    """``(cov, cov_white, deff, block)``: ``cov_white = s^2 (J'J)^-1`` (``s^2 = r'r / dof``),
    ``deff`` the mean generalised design effect of the block jackknife's covariance against
    it, ``cov = deff cov_white`` (method.md §9), and the jackknife's block length (rows)."""
    J, r = np.asarray(J, float), np.asarray(r, float)
    s2 = float(r @ r) / max(dof, 1)
    d = 1.0 / np.maximum(np.linalg.norm(J, axis=0), 1e-300)
    white_s = s2 * np.linalg.pinv((J * d).T @ (J * d))  # in the columns' unit scale
    jack, block = block_jackknife_cov(J, r)
    jack_s = jack / np.outer(d, d)
    deff = float(np.trace(np.linalg.pinv(white_s) @ jack_s)) / J.shape[1]
    if not np.isfinite(deff) or deff <= 0:
        deff = 1.0
    white = white_s * np.outer(d, d)
    return deff * white, white, deff, block
