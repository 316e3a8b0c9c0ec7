"""Levenberg–Marquardt on stacked Tikhonov residuals, returning an account of itself.

Both fits (M3 for the accelerometer, M5 for the gyroscope) minimise
``|r_data(theta)|^2 + lambda |theta - theta_0|^2`` by appending ``sqrt(lambda) (theta - theta_0)``
to the data residuals, so the solver sees one least-squares problem and never squares twice
(the thesis's code does, method.md §3).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares


@dataclass(frozen=True)
class FitReport:
    """What a fit did: where it started, where it ended, and why it stopped."""

    theta: np.ndarray
    start: np.ndarray
    start_name: str
    lam: float
    cost_start: float  # |r_data|^2 + lambda |theta - theta_0|^2 at the start
    cost: float  # the same at the solution
    data_cost: float  # |r_data|^2 at the solution
    nfev: int
    status: int
    message: str
    jac_cond: float  # condition number of the data Jacobian at the solution
    std: np.ndarray  # per-parameter standard errors (sandwich form, see below)
    cov: np.ndarray  # (p, p) covariance behind ``std``
    jac: np.ndarray  # (n, p) data Jacobian at the solution
    trace_theta: np.ndarray  # (I, p) parameters at each accepted step
    trace_cost: np.ndarray  # (I,) regularised cost at each accepted step
    n_data: int

    @property
    def residual_norm(self) -> float:
        return float(np.sqrt(self.data_cost))

    def solution_norm(self, theta0: np.ndarray) -> float:
        return float(np.linalg.norm(self.theta - theta0))


def fit_tikhonov(
    residuals: Callable[[np.ndarray], np.ndarray],
    jacobian: Callable[[np.ndarray], np.ndarray] | None,
    start: np.ndarray,
    theta0: np.ndarray,
    lam: float,
    start_name: str = "prior",
    max_nfev: int | None = None,
) -> FitReport:
    """Minimise ``|residuals(theta)|^2 + lam |theta - theta0|^2`` by LM from ``start``.

    ``jacobian`` returns d residuals / d theta of the data part; ``None`` means finite
    differences. The standard errors use the sandwich form of the regularised estimator,
    ``cov = s^2 H^-1 J'J H^-1`` with ``H = J'J + lam I`` and ``s^2 = |r|^2 / (n - p)``: with
    ``lam = 0`` it is the usual ``s^2 (J'J)^-1``.
    """
    sq = np.sqrt(lam)
    p = len(theta0)
    trace_t: list[np.ndarray] = []
    trace_c: list[float] = []
    best = [np.inf]

    def fun(theta: np.ndarray) -> np.ndarray:
        r = np.concatenate([residuals(theta), sq * (theta - theta0)])
        c = float(r @ r)
        # LM only moves to a trial point that lowers the cost: the running minimum of the
        # evaluations is the sequence of accepted steps.
        if c < best[0]:
            best[0] = c
            trace_t.append(theta.copy())
            trace_c.append(c)
        return r

    jac = None
    if jacobian is not None:
        eye = sq * np.eye(p)

        def jac(theta: np.ndarray) -> np.ndarray:
            return np.vstack([jacobian(theta), eye])

    r0 = fun(np.asarray(start, float))
    cost_start = float(r0 @ r0)
    if not np.isfinite(cost_start):
        raise FloatingPointError("non-finite residual at the start point")
    res = least_squares(fun, np.asarray(start, float), jac=jac if jac else "2-point",
                        method="lm", x_scale="jac", max_nfev=max_nfev)
    theta = res.x
    r_data = residuals(theta)
    n = len(r_data)
    data_cost = float(r_data @ r_data)
    J = jacobian(theta) if jacobian is not None else res.jac[:n]
    cov, cond = sandwich_cov(J, lam, data_cost / max(n - p, 1))
    return FitReport(
        theta=theta, start=np.asarray(start, float), start_name=start_name, lam=float(lam),
        cost_start=cost_start, cost=float(res.fun @ res.fun), data_cost=data_cost,
        nfev=int(res.nfev), status=int(res.status), message=str(res.message),
        jac_cond=cond, std=np.sqrt(np.clip(np.diag(cov), 0, None)), cov=cov, jac=J,
        trace_theta=np.array(trace_t), trace_cost=np.array(trace_c),
        n_data=n,
    )


def sandwich_cov(J: np.ndarray, lam: float, s2: float, meat: np.ndarray | None = None
                 ) -> tuple[np.ndarray, float]:
    """Covariance of the regularised estimate, ``H^-1 J' S J H^-1`` with ``H = J'J + lam I``.

    ``S`` is the residuals' covariance: ``s2 I`` by default, else ``s2 I + meat`` where
    ``meat`` (n, n) adds correlated error sources. Returns it with cond(J).
    """
    p = J.shape[1]
    sv = np.linalg.svd(J, compute_uv=False)
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")
    JtJ = J.T @ J
    try:
        Hi = np.linalg.inv(JtJ + lam * np.eye(p))
    except np.linalg.LinAlgError:
        return np.full((p, p), np.inf), cond
    mid = s2 * JtJ
    if meat is not None:
        mid = mid + J.T @ meat @ J
    return Hi @ mid @ Hi, cond
