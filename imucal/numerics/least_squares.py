"""Levenberg–Marquardt on stacked Tikhonov residuals, returning an account of itself.

Both fits (M3 for the accelerometer, M5 for the gyroscope) minimise
``|r_data(theta)|^2 + lambda |theta - theta_0|^2`` by appending ``sqrt(lambda) (theta - theta_0)``
to the data residuals, so the solver sees one least-squares problem and never squares twice
(the thesis's code does, method.md §3). The solver is ``scipy.optimize.least_squares``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from scipy.optimize import OptimizeResult

# scipy's forward-difference step, sqrt(machine epsilon) relative (its "2-point" rule)
_FD_STEP = float(np.sqrt(np.finfo(float).eps))


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
    nfev: int  # residual evaluations (MINPACK's count)
    njev: int  # Jacobian evaluations: one per LM iteration
    status: int  # scipy.optimize.least_squares' status (1-4 converged, 0 max_nfev reached)
    message: str  # and its message
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

    ``scipy.optimize.least_squares(method="lm", x_scale="jac")`` with its default tolerances
    ``ftol = xtol = gtol = 1e-8`` and ``max_nfev = 100 p`` when not given: MINPACK's ``lmder``.
    "lm" always applies here: the ``p`` Tikhonov rows make the stacked problem at least as tall
    as it is wide whatever the data, there are no bounds, and the problems are small and dense
    (9 or 12 parameters, at most some thousands of residuals), where MINPACK is the fastest of
    scipy's three methods. ``x_scale="jac"`` is MINPACK's own column scaling (scipy's default
    only since 1.16), stated so that older scipy takes the same steps.

    ``jacobian`` returns d residuals / d theta of the data part; ``None`` means forward
    differences with scipy's step. The standard errors use the sandwich form of the
    regularised estimator, ``cov = s^2 H^-1 J'J H^-1`` with ``H = J'J + lam I`` and
    ``s^2 = |r|^2 / (n - p)``: with ``lam = 0`` it is the usual ``s^2 (J'J)^-1``.
    Raises ``FloatingPointError`` when the residuals at ``start`` are not finite.
    """
    # imported here, where a fit runs: scipy.optimize costs ~0.2 s CPU to import (it pulls in
    # scipy.linalg, scipy.fft, scipy.special), not paid by loading a session or a calibration
    from scipy.optimize import least_squares

    start = np.array(start, dtype=float)
    problem = _StackedProblem(residuals, jacobian, theta0, lam)
    res = least_squares(problem.fun, start, jac=problem.jac, method="lm", x_scale="jac",
                        max_nfev=max_nfev)
    return _account(res, problem, start, start_name, lam)


class _StackedProblem:
    """The stacked residuals ``(r_data(theta), sqrt(lam) (theta - theta0))`` and their Jacobian
    as scipy asks for them, recording on the way the accepted steps (the fit's trace) and the
    latest data residuals (reused by the forward differences)."""

    def __init__(self, residuals: Callable[[np.ndarray], np.ndarray],
                 jacobian: Callable[[np.ndarray], np.ndarray] | None,
                 theta0: np.ndarray, lam: float):
        self.residuals, self.jacobian, self.theta0 = residuals, jacobian, theta0
        self.sq = np.sqrt(lam)
        self.p = len(theta0)
        self.eye = self.sq * np.eye(self.p)
        self.trace_t: list[np.ndarray] = []
        self.trace_c: list[float] = []
        self.last: list[tuple[np.ndarray, np.ndarray]] = []  # the latest (theta, r_data)

    def fun(self, theta: np.ndarray) -> np.ndarray:
        r_data = np.asarray(self.residuals(theta), dtype=float)
        r = np.concatenate([r_data, self.sq * (theta - self.theta0)])
        c = float(r @ r)
        if not self.trace_c:  # scipy evaluates the start first
            if not np.isfinite(c):
                raise FloatingPointError("non-finite residual at the start point")
            self.trace_t.append(theta.copy())
            self.trace_c.append(c)
        elif c < self.trace_c[-1]:
            # LM only moves to a trial point that lowers the cost: the running minimum of the
            # evaluations is the sequence of accepted steps.
            self.trace_t.append(theta.copy())
            self.trace_c.append(c)
        self.last[:] = [(theta.copy(), r_data)]
        return r

    def jac(self, theta: np.ndarray) -> np.ndarray:
        if self.jacobian is not None:
            data = np.asarray(self.jacobian(theta), dtype=float)
        else:
            data = _forward_difference(self.residuals, theta, self.last)
        return np.vstack([data, self.eye])


def _account(res: OptimizeResult, problem: _StackedProblem, start: np.ndarray, start_name: str,
             lam: float) -> FitReport:
    """The :class:`FitReport` of scipy's result ``res`` on ``problem``: the data residuals and
    Jacobian are the stacked ones' first ``n`` rows, as LM evaluated them at the solution."""
    p = problem.p
    n = len(res.fun) - p
    r_data = res.fun[:n]
    data_cost = float(r_data @ r_data)
    J = np.array(res.jac[:n])
    cov, cond = sandwich_cov(J, lam, data_cost / max(n - p, 1))
    return FitReport(
        theta=res.x, start=start, start_name=start_name, lam=float(lam),
        cost_start=problem.trace_c[0], cost=float(res.fun @ res.fun), data_cost=data_cost,
        nfev=int(res.nfev), njev=int(res.njev or 0), status=int(res.status),
        message=str(res.message), jac_cond=cond, std=np.sqrt(np.clip(np.diag(cov), 0, None)),
        cov=cov, jac=J, trace_theta=np.array(problem.trace_t),
        trace_cost=np.array(problem.trace_c), n_data=n,
    )


def _forward_difference(f: Callable[[np.ndarray], np.ndarray], x: np.ndarray,
                        last: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """d f / d x by forward differences with scipy's "2-point" step
    ``sqrt(eps) sign(x) max(1, |x|)``, reusing ``f(x)`` when it was the latest evaluation
    (LM always evaluates the residuals at a point before asking for its Jacobian). Its
    evaluations bypass the fit's trace: they are not steps."""
    f0 = last[0][1] if last and np.array_equal(last[0][0], x) else np.asarray(f(x), float)
    h = _FD_STEP * np.where(x >= 0, 1.0, -1.0) * np.maximum(1.0, np.abs(x))
    cols = []
    for i in range(len(x)):  # one column per parameter (9 or 12), not per sample
        x1 = x.copy()
        x1[i] += h[i]
        cols.append((np.asarray(f(x1), float) - f0) / (x1[i] - x[i]))
    return np.column_stack(cols)


class FactoredCov:
    """An (n, n) covariance kept as ``U C U' + B``, never formed densely.

    ``U`` (n, r) and ``C`` (r, r) carry an error shared by all rows (a calibration's own
    uncertainty), ``B`` is block-tridiagonal in 3 x 3 blocks: ``diag`` (m, 3, 3) and ``upper``
    (m - 1, 3, 3) the blocks ``B[k, k+1]`` (``B[k+1, k] = upper[k]'``; ``None`` for zero). With
    thousands of static blocks the dense form would cost ``O(n^2)`` memory and ``O(n^3)`` time;
    this one costs ``O(n)``. ``np.asarray`` gives the dense matrix.
    """

    def __init__(self, U: np.ndarray, C: np.ndarray, diag: np.ndarray,
                 upper: np.ndarray | None = None):
        self.U = np.asarray(U, float)
        self.C = np.asarray(C, float)
        self.diag = np.asarray(diag, float)
        self.upper = None if upper is None else np.asarray(upper, float)
        self.shape = (len(self.U), len(self.U))

    def dense(self) -> np.ndarray:
        out = self.U @ self.C @ self.U.T
        m = len(self.diag)
        v = out.reshape(m, 3, m, 3)
        idx = np.arange(m)
        v[idx, :, idx, :] += self.diag
        if self.upper is not None and m > 1:
            v[idx[:-1], :, idx[1:], :] += self.upper
            v[idx[1:], :, idx[:-1], :] += np.transpose(self.upper, (0, 2, 1))
        return out

    def __array__(self, dtype=None, copy=None):
        out = self.dense()
        return out if dtype is None else out.astype(dtype)

    def select(self, keep: np.ndarray) -> FactoredCov:
        """The covariance of the 3 x 3 blocks where ``keep`` (m,) is true, still factored: a
        coupling block survives only between two kept blocks that were neighbours."""
        keep = np.asarray(keep, bool)
        idx = np.flatnonzero(keep)
        U = self.U.reshape(len(self.diag), 3, -1)[idx].reshape(3 * len(idx), -1)
        upper = None
        if self.upper is not None and len(idx) > 1:
            upper = np.where((np.diff(idx) == 1)[:, None, None], self.upper[idx[:-1]], 0.0)
        return FactoredCov(U, self.C, self.diag[idx], upper)

    def trace(self) -> float:
        low = float(np.einsum("ij,ij->", self.U @ self.C, self.U))
        return low + float(np.einsum("kii->", self.diag))

    def quad(self, J: np.ndarray) -> np.ndarray:
        """``J' (U C U' + B) J`` for J (n, p)."""
        V = self.U.T @ J
        out = V.T @ self.C @ V
        Jk = J.reshape(len(self.diag), 3, -1)
        out += np.einsum("kip,kiq->pq", Jk, self.diag @ Jk)
        if self.upper is not None and len(Jk) > 1:
            X = np.einsum("kip,kiq->pq", Jk[:-1], self.upper @ Jk[1:])
            out += X + X.T
        return out


def trace_of(meat: np.ndarray | FactoredCov) -> float:
    return meat.trace() if isinstance(meat, FactoredCov) else float(np.trace(meat))


def sandwich_cov(J: np.ndarray, lam: float, s2: float,
                 meat: np.ndarray | FactoredCov | None = None) -> tuple[np.ndarray, float]:
    """Covariance of the regularised estimate, ``H^-1 J' S J H^-1`` with ``H = J'J + lam I``.

    ``S`` is the residuals' covariance: ``s2 I`` by default, else ``s2 I + meat`` where
    ``meat`` (n, n), dense or :class:`FactoredCov`, adds correlated error sources. Returns it
    with cond(J).
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
    if isinstance(meat, FactoredCov):
        mid = mid + meat.quad(J)
    elif meat is not None:
        mid = mid + J.T @ meat @ J
    return Hi @ mid @ Hi, cond
