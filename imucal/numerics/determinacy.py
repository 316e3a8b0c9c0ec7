"""What the data alone determine of a regularised least-squares fit (issue 27).

A Tikhonov fit, ``|r(theta)|^2 + lambda |theta - theta_0|^2``, returns a finite answer whatever
the data: where the data say nothing about a parameter, the prior term holds it at
``theta_0`` and the regularised estimator's covariance, ``H^-1 J' S J H^-1`` with
``H = J'J + lambda I``, comes out near zero there (the prior is counted as a measurement).
A coplanar session measured so gave an accelerometer scale of 1.000014 +- 0.0000055 against a
truth of 0.956.

Here the standard errors are the data's alone, the covariance of the unregularised estimate
``(J'J)^-1 J' S J (J'J)^-1`` (``S = s2 I + meat``), and a parameter whose data-only standard
error exceeds its limit is *undetermined*: no finite error is reported for it. Each error is
the marginal one, every other parameter free: holding the undetermined ones at their values
and reporting the others' errors given them would be a finer figure that lies, for a
parameter held wrong biases the rest (in that coplanar session, a bias held 110 mg off put two
scales 90 of such conditional errors off).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from imucal.numerics.least_squares import FactoredCov


@dataclass(frozen=True)
class Determinacy:
    """The data-only standard errors of a fit and the parameters the data leave open."""

    std: np.ndarray  # (p,) data-only standard errors, NaN where undetermined
    undetermined: tuple[str, ...]  # names of those past their limit, in the names' order
    data_std: np.ndarray  # (p,) the data-only errors, the undetermined ones' too


def _data_cov(J: np.ndarray, s2: float, meat: np.ndarray | FactoredCov | None) -> np.ndarray:
    """``(J'J)^-1 J' (s2 I + meat) J (J'J)^-1`` through the SVD of ``J``: a direction of
    parameter space the data do not see (singular value 0) gets a variance past any limit."""
    U, sv, Vt = np.linalg.svd(J, full_matrices=False)
    if sv.size == 0 or not sv[0] > 0:  # no data at all (every turn left out), or none that moves
        return np.full((J.shape[1], J.shape[1]), np.inf)
    if meat is None:
        mid = s2 * np.eye(len(sv))
    elif isinstance(meat, FactoredCov):
        mid = s2 * np.eye(len(sv)) + meat.quad(U)
    else:
        mid = s2 * np.eye(len(sv)) + U.T @ np.asarray(meat) @ U
    # A direction the data do not see at all (rounding's singular value) gets the variance of
    # one seen 1e14 times more weakly than the best: finite arithmetic, and far past any limit.
    A = Vt.T / np.maximum(sv, sv[0] * 1e-14)  # V S^-1
    cov = A @ mid @ A.T
    return cov


def _std(cov: np.ndarray) -> np.ndarray:
    d = np.diag(cov).copy()
    return np.sqrt(np.where(np.isfinite(d), np.clip(d, 0, None), np.inf))


def determinacy(J: np.ndarray, s2: float, names: Sequence[str], limits: np.ndarray | float,
                meat: np.ndarray | FactoredCov | None = None) -> Determinacy:
    """Data-only standard errors of the parameters of ``J`` (n, p), the data Jacobian at the
    solution (weighted: each residual of variance ``s2``, plus ``meat`` (n, n) where the
    residuals share errors), and which exceed ``limits`` (p,) or a scalar: see the module."""
    J = np.asarray(J, float)
    p = J.shape[1]
    lim = np.broadcast_to(np.asarray(limits, float), (p,))
    data_std = _std(_data_cov(J, s2, meat))
    over = data_std > lim
    return Determinacy(std=np.where(over, np.nan, data_std),
                       undetermined=tuple(n for n, o in zip(names, over) if o),
                       data_std=data_std)
