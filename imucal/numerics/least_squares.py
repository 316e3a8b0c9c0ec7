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
    res = least_squares_lm(fun, np.asarray(start, float), jac, max_nfev=max_nfev, f0=r0)
    theta = res.x
    n = len(res.fun) - p
    r_data = res.fun[:n]  # the residuals at theta, as LM evaluated them there
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


# --- Levenberg-Marquardt: MINPACK's lmder, as scipy.optimize.least_squares(method="lm") runs it --


BACKEND = "numpy"  # "scipy" runs scipy.optimize.least_squares instead (for comparison)
_EPS = float(np.finfo(float).eps)
_DWARF = float(np.finfo(float).tiny)
_TERMINATION = {
    -1: "Improper input parameters status returned from `leastsq`",
    0: "The maximum number of function evaluations is exceeded.",
    1: "`gtol` termination condition is satisfied.",
    2: "`ftol` termination condition is satisfied.",
    3: "`xtol` termination condition is satisfied.",
    4: "Both `ftol` and `xtol` termination conditions are satisfied.",
}
# MINPACK's info to least_squares' status; 6-8 (tolerances below machine precision) read as
# the ftol / xtol / gtol conditions they refine.
_FROM_MINPACK = {0: -1, 1: 2, 2: 3, 3: 4, 4: 1, 5: 0, 6: 2, 7: 3, 8: 1}


@dataclass(frozen=True)
class LMResult:
    x: np.ndarray
    fun: np.ndarray  # residuals at x
    jac: np.ndarray  # Jacobian at x
    nfev: int
    status: int
    message: str


def least_squares_lm(fun: Callable[[np.ndarray], np.ndarray],
                     x0: np.ndarray,
                     jac: Callable[[np.ndarray], np.ndarray] | None = None,
                     ftol: float = 1e-8, xtol: float = 1e-8, gtol: float = 1e-8,
                     max_nfev: int | None = None, f0: np.ndarray | None = None) -> LMResult:
    """``scipy.optimize.least_squares(fun, x0, jac or "2-point", method="lm", x_scale="jac")``
    without scipy: the same algorithm (MINPACK's ``lmder``: Levenberg-Marquardt with the trust
    region of More 1978, internal column scaling, factor 100) and the same calls of ``fun``.

    scipy's own wrapper costs about a millisecond per call and importing scipy.optimize half a
    second, more than the fits themselves on small problems (the L-curve and the grouping run
    dozens of them). The arithmetic is MINPACK's up to rounding (column operations are numpy
    dot products here), so results agree with scipy's to rounding; ``BACKEND = "scipy"``
    switches to scipy for comparison. ``jac=None`` means forward differences with scipy's step
    ``sqrt(eps) max(1, |x|)``; ``fun`` is evaluated at the same points in the same order as
    under scipy (its caching included), so a caller that watches the evaluations sees the same.
    ``f0``, when given, is ``fun(x0)`` already evaluated (scipy would evaluate it again).
    """
    x0 = np.array(x0, dtype=float)
    if BACKEND == "scipy":
        from scipy.optimize import least_squares

        res = least_squares(fun, x0, jac=jac if jac is not None else "2-point", method="lm",
                            x_scale="jac", ftol=ftol, xtol=xtol, gtol=gtol, max_nfev=max_nfev)
        return LMResult(x=res.x, fun=res.fun, jac=res.jac, nfev=int(res.nfev),
                        status=int(res.status), message=str(res.message))
    vf = _VectorFunction(fun, jac, x0, f0)
    if not np.all(np.isfinite(vf.f)):
        raise ValueError("Residuals are not finite in the initial point.")
    n = x0.size
    if vf.f.size < n:
        raise ValueError("Method 'lm' doesn't work when the number of residuals is less than "
                         "the number of variables.")
    x, fvec, nfev, info = _lmder(vf.fun, vf.jac, x0, ftol, xtol, gtol,
                                 100 * n if max_nfev is None else max_nfev, 100.0)
    J = vf.jac(x)
    status = _FROM_MINPACK[info]
    return LMResult(x=x, fun=fvec, jac=J, nfev=nfev, status=status, message=_TERMINATION[status])


class _VectorFunction:
    """scipy's caching of ``fun`` and its Jacobian at the last point asked for."""

    def __init__(self, fun, jac, x0: np.ndarray, f0: np.ndarray | None = None):
        self._fun, self._jac = fun, jac
        self.x = x0.copy()
        self.f = self._call(self.x) if f0 is None else np.array(f0, dtype=float)
        self.J = self._jacobian()
        self.f_ok = self.J_ok = True

    def _call(self, x: np.ndarray) -> np.ndarray:
        return np.atleast_1d(np.asarray(self._fun(x.copy()), dtype=float))

    def _jacobian(self) -> np.ndarray:
        if self._jac is not None:
            return np.atleast_2d(np.asarray(self._jac(self.x.copy()), dtype=float))
        # scipy's "2-point": h = sqrt(eps) sign(x) max(1, |x|), sign(0) = 1
        x0, f0 = self.x, self.f
        h = _EPS ** 0.5 * ((x0 >= 0).astype(float) * 2 - 1) * np.maximum(1.0, np.abs(x0))
        Jt = np.empty((x0.size, f0.size))
        for i in range(x0.size):
            x1 = x0.copy()
            x1[i] = x0[i] + h[i]
            Jt[i] = (self._call(x1) - f0) / ((x0[i] + h[i]) - x0[i])
        return Jt.T

    def _move(self, x: np.ndarray) -> None:
        if not np.array_equal(x, self.x):
            self.x = np.array(x, dtype=float)
            self.f_ok = self.J_ok = False

    def fun(self, x: np.ndarray) -> np.ndarray:
        self._move(x)
        if not self.f_ok:
            self.f = self._call(self.x)
            self.f_ok = True
        return self.f.copy()

    def jac(self, x: np.ndarray) -> np.ndarray:
        self._move(x)
        if not self.J_ok:
            if self._jac is None and not self.f_ok:
                self.f = self._call(self.x)
                self.f_ok = True
            self.J = self._jacobian()
            self.J_ok = True
        return self.J.copy()


def _lmder(fcn, jacf, x, ftol: float, xtol: float, gtol: float, maxfev: int, factor: float):
    """MINPACK lmder (More, Garbow, Hillstrom 1980), mode 1, no printing. Returns the solution,
    its residuals, the number of residual evaluations and MINPACK's ``info``."""
    n = x.size
    x = x.copy()
    fvec = fcn(x)
    nfev = 1
    fnorm = _norm(fvec)
    par = 0.0
    it = 1
    diag = None
    delta = xnorm = 0.0
    while True:
        # outer loop: Jacobian, its QR factorisation with column pivoting, Q'f
        R, ipvt, acnorm, qtf = _qr_solve_parts(jacf(x), fvec)
        if it == 1:
            diag = np.where(acnorm == 0.0, 1.0, acnorm)
            xnorm = _norm(diag * x)
            delta = factor * xnorm
            if delta == 0.0:
                delta = factor
        gnorm = 0.0
        if fnorm != 0.0:
            for j in range(n):
                a = acnorm[ipvt[j]]
                if a != 0.0:
                    s = 0.0
                    for i in range(j + 1):
                        s += R[i][j] * (qtf[i] / fnorm)
                    gnorm = max(gnorm, abs(s / a))
        if gnorm <= gtol:
            return x, fvec, nfev, 4
        diag = np.maximum(diag, acnorm)
        diag_l = diag.tolist()
        while True:
            # inner loop: LM parameter and trial step
            par, step = _lmpar(R, ipvt, diag_l, qtf, delta, par)
            p = -np.array(step)
            x_new = x + p
            pnorm = _norm(diag * p)
            if it == 1:
                delta = min(delta, pnorm)
            f_new = fcn(x_new)
            nfev += 1
            fnorm1 = _norm(f_new)
            actred = -1.0
            if 0.1 * fnorm1 < fnorm:
                actred = 1.0 - (fnorm1 / fnorm) ** 2
            pl = p.tolist()
            wa3 = [0.0] * n
            for j in range(n):
                t = pl[ipvt[j]]
                for i in range(j + 1):
                    wa3[i] += R[i][j] * t
            temp1 = _norm(np.array(wa3)) / fnorm
            temp2 = np.sqrt(par) * pnorm / fnorm
            prered = temp1 * temp1 + temp2 * temp2 / 0.5
            dirder = -(temp1 * temp1 + temp2 * temp2)
            ratio = actred / prered if prered != 0.0 else 0.0
            if ratio <= 0.25:
                temp = 0.5 if actred >= 0.0 else 0.5 * dirder / (dirder + 0.5 * actred)
                if 0.1 * fnorm1 >= fnorm or temp < 0.1:
                    temp = 0.1
                delta = temp * min(delta, pnorm / 0.1)
                par /= temp
            elif par == 0.0 or ratio >= 0.75:
                delta = pnorm / 0.5
                par = 0.5 * par
            if ratio >= 1e-4:
                x = x_new
                fvec = f_new
                xnorm = _norm(diag * x)
                fnorm = fnorm1
                it += 1
            info = 0
            small = abs(actred) <= ftol and prered <= ftol and 0.5 * ratio <= 1.0
            if small:
                info = 1
            if delta <= xtol * xnorm:
                info = 2
            if small and info == 2:
                info = 3
            if info:
                return x, fvec, nfev, info
            if nfev >= maxfev:
                info = 5
            if abs(actred) <= _EPS and prered <= _EPS and 0.5 * ratio <= 1.0:
                info = 6
            if delta <= _EPS * xnorm:
                info = 7
            if gnorm <= _EPS:
                info = 8
            if info:
                return x, fvec, nfev, info
            if ratio >= 1e-4:
                break


def _norm(v: np.ndarray) -> float:
    return float(np.sqrt(np.dot(v, v)))


def _qr_solve_parts(J: np.ndarray, fvec: np.ndarray):
    """MINPACK qrfac with column pivoting on J (m, n), then Q' fvec.

    Returns R (n x n upper triangle as nested lists, rows), the pivot ``ipvt`` (0-based), the
    column norms of J and the first n components of Q' fvec.

    A tall J is first reduced by LAPACK's unpivoted Householder QR of ``[J, fvec]``: its
    triangle ``R1`` has J's column norms and Gram matrix, and its last column is
    ``Q1' fvec``, so MINPACK's pivoted factorisation of ``R1`` (n x n, cheap) gives the same
    ``R`` and ``Q' fvec`` (up to the signs of rows, which the LM step does not see).
    """
    J = np.asarray(J, dtype=float)
    m, n = J.shape
    if m > 2 * n:
        Raug = np.linalg.qr(np.column_stack([J, fvec]), mode="r")
        R, ipvt, qtf = _qrfac_small(Raug[:n, :n].T.tolist(), Raug[:n, n].tolist())
        return R, ipvt, np.sqrt(np.einsum("ij,ij->j", J, J)), qtf
    A = J.T.copy()  # rows are J's columns: column operations contiguous
    n, m = A.shape
    acnorm = np.sqrt(np.einsum("ij,ij->i", A, A))
    rdiag = acnorm.copy()
    wa = rdiag.copy()
    ipvt = list(range(n))
    for j in range(min(m, n)):
        kmax = j + int(np.argmax(rdiag[j:]))
        if kmax != j:
            A[[j, kmax]] = A[[kmax, j]]
            rdiag[kmax] = rdiag[j]
            wa[kmax] = wa[j]
            ipvt[j], ipvt[kmax] = ipvt[kmax], ipvt[j]
        u = A[j, j:]
        ajnorm = _norm(u)
        if ajnorm != 0.0:
            if u[0] < 0.0:
                ajnorm = -ajnorm
            u /= ajnorm
            u[0] += 1.0
            if j + 1 < n:
                rest = A[j + 1:, j:]
                temp = (rest @ u) / u[0]
                rest -= temp[:, None] * u[None, :]
                nz = rdiag[j + 1:] != 0.0
                if nz.any():
                    k = np.flatnonzero(nz) + j + 1
                    t = A[k, j] / rdiag[k]
                    rdiag[k] *= np.sqrt(np.maximum(0.0, 1.0 - t * t))
                    redo = k[0.05 * (rdiag[k] / wa[k]) ** 2 <= _EPS]
                    for kk in redo:
                        rdiag[kk] = _norm(A[kk, j + 1:])
                        wa[kk] = rdiag[kk]
        rdiag[j] = -ajnorm
    # Q' f: apply the Householder reflections in order
    w = np.array(fvec, dtype=float)
    qtf = [0.0] * n
    for j in range(n):
        u = A[j, j:]
        if u[0] != 0.0:
            temp = -float(u @ w[j:]) / u[0]
            w[j:] += u * temp
        qtf[j] = float(w[j])
    R = [[0.0] * n for _ in range(n)]
    for i in range(n):
        R[i][i] = float(rdiag[i])
        for k in range(i + 1, n):
            R[i][k] = float(A[k, i])
    return R, ipvt, acnorm, qtf


def _qrfac_small(cols: list, f: list):
    """MINPACK qrfac with column pivoting, then Q' f, on a small matrix in plain Python
    (``cols[k]`` is column k; numpy's per-call overhead dominates at this size). Returns R
    (nested lists, rows), the pivot (0-based) and the first n components of Q' f."""
    n = len(cols)
    m = len(cols[0])
    cols = [list(c) for c in cols]
    rdiag = [_fnorm(c) for c in cols]
    wa = list(rdiag)
    ipvt = list(range(n))
    for j in range(min(m, n)):
        kmax = j
        for k in range(j, n):
            if rdiag[k] > rdiag[kmax]:
                kmax = k
        if kmax != j:
            cols[j], cols[kmax] = cols[kmax], cols[j]
            rdiag[kmax] = rdiag[j]
            wa[kmax] = wa[j]
            ipvt[j], ipvt[kmax] = ipvt[kmax], ipvt[j]
        u = cols[j]
        ajnorm = _fnorm(u[j:])
        if ajnorm != 0.0:
            if u[j] < 0.0:
                ajnorm = -ajnorm
            for i in range(j, m):
                u[i] /= ajnorm
            u[j] += 1.0
            ujj = u[j]
            for k in range(j + 1, n):
                c = cols[k]
                s = 0.0
                for i in range(j, m):
                    s += u[i] * c[i]
                t = s / ujj
                for i in range(j, m):
                    c[i] -= t * u[i]
                if rdiag[k] != 0.0:
                    t = c[j] / rdiag[k]
                    rdiag[k] *= max(0.0, 1.0 - t * t) ** 0.5
                    if 0.05 * (rdiag[k] / wa[k]) ** 2 <= _EPS:
                        rdiag[k] = _fnorm(c[j + 1:])
                        wa[k] = rdiag[k]
        rdiag[j] = -ajnorm
    w = list(f)
    qtf = [0.0] * n
    for j in range(n):
        u = cols[j]
        if u[j] != 0.0:
            s = 0.0
            for i in range(j, m):
                s += u[i] * w[i]
            t = -s / u[j]
            for i in range(j, m):
                w[i] += u[i] * t
        qtf[j] = w[j]
    R = [[0.0] * n for _ in range(n)]
    for i in range(n):
        R[i][i] = rdiag[i]
        for k in range(i + 1, n):
            R[i][k] = cols[k][i]
    return R, ipvt, qtf


def _lmpar(R: list, ipvt: list, diag: list, qtb: list, delta: float, par: float):
    """MINPACK lmpar: the LM parameter for which the step's scaled norm is about ``delta``.

    ``R`` (nested lists) is the upper triangular factor of the pivoted Jacobian; its strict
    lower triangle is used as work space (MINPACK's ``s``). Returns ``par`` and the step.
    """
    n = len(R)
    nsing = n
    wa1 = list(qtb)
    for j in range(n):
        if R[j][j] == 0.0 and nsing == n:
            nsing = j
        if nsing < n:
            wa1[j] = 0.0
    for j in range(nsing - 1, -1, -1):
        wa1[j] /= R[j][j]
        t = wa1[j]
        for i in range(j):
            wa1[i] -= R[i][j] * t
    x = [0.0] * n
    for j in range(n):
        x[ipvt[j]] = wa1[j]
    it = 0
    wa2 = [diag[j] * x[j] for j in range(n)]
    dxnorm = _fnorm(wa2)
    fp = dxnorm - delta
    if fp <= 0.1 * delta:
        return 0.0, x
    parl = 0.0
    if nsing >= n:
        wa1 = [diag[ipvt[j]] * (wa2[ipvt[j]] / dxnorm) for j in range(n)]
        for j in range(n):
            s = 0.0
            for i in range(j):
                s += R[i][j] * wa1[i]
            wa1[j] = (wa1[j] - s) / R[j][j]
        t = _fnorm(wa1)
        parl = fp / delta / t / t
    for j in range(n):
        s = 0.0
        for i in range(j + 1):
            s += R[i][j] * qtb[i]
        wa1[j] = s / diag[ipvt[j]]
    gnorm = _fnorm(wa1)
    paru = gnorm / delta
    if paru == 0.0:
        paru = _DWARF / min(delta, 0.1)
    par = max(par, parl)
    par = min(par, paru)
    if par == 0.0:
        par = gnorm / dxnorm
    while True:
        it += 1
        if par == 0.0:
            par = max(_DWARF, 0.001 * paru)
        t = par ** 0.5
        x, sdiag = _qrsolv(R, ipvt, [t * d for d in diag], qtb)
        wa2 = [diag[j] * x[j] for j in range(n)]
        dxnorm = _fnorm(wa2)
        temp = fp
        fp = dxnorm - delta
        if abs(fp) <= 0.1 * delta or (parl == 0.0 and fp <= temp and temp < 0.0) or it == 10:
            return par, x
        if dxnorm == 0.0:
            return par, x
        wa1 = [diag[ipvt[j]] * (wa2[ipvt[j]] / dxnorm) for j in range(n)]
        for j in range(n):
            wa1[j] /= sdiag[j]
            t = wa1[j]
            for i in range(j + 1, n):
                wa1[i] -= R[i][j] * t
        t = _fnorm(wa1)
        parc = fp / delta / t / t
        if fp > 0.0:
            parl = max(parl, par)
        if fp < 0.0:
            paru = min(paru, par)
        par = max(parl, par + parc)


def _fnorm(v: list) -> float:
    s = 0.0
    for a in v:
        s += a * a
    return s ** 0.5


def _qrsolv(R: list, ipvt: list, diag: list, qtb: list):
    """MINPACK qrsolv: least squares solution of ``J x = b, D x = 0`` from the QR factors, by
    Givens rotations; leaves ``s`` (strict part) in R's strict lower triangle. Returns x and
    the diagonal of ``s``."""
    n = len(R)
    x = [0.0] * n
    wa = list(qtb)
    for j in range(n):
        for i in range(j, n):
            R[i][j] = R[j][i]
        x[j] = R[j][j]
    sdiag = [0.0] * n
    for j in range(n):
        d = diag[ipvt[j]]
        if d != 0.0:
            for k in range(j, n):
                sdiag[k] = 0.0
            sdiag[j] = d
            qtbpj = 0.0
            for k in range(j, n):
                sk = sdiag[k]
                if sk != 0.0:
                    rkk = R[k][k]
                    if abs(rkk) < abs(sk):
                        cotan = rkk / sk
                        sin = 0.5 / (0.25 + 0.25 * (cotan * cotan)) ** 0.5
                        cos = sin * cotan
                    else:
                        tan = sk / rkk
                        cos = 0.5 / (0.25 + 0.25 * (tan * tan)) ** 0.5
                        sin = cos * tan
                    temp = cos * wa[k] + sin * qtbpj
                    qtbpj = -sin * wa[k] + cos * qtbpj
                    wa[k] = temp
                    R[k][k] = cos * rkk + sin * sk
                    for i in range(k + 1, n):
                        rik = R[i][k]
                        si = sdiag[i]
                        R[i][k] = cos * rik + sin * si
                        sdiag[i] = -sin * rik + cos * si
        sdiag[j] = R[j][j]
        R[j][j] = x[j]
    nsing = n
    for j in range(n):
        if sdiag[j] == 0.0 and nsing == n:
            nsing = j
        if nsing < n:
            wa[j] = 0.0
    for j in range(nsing - 1, -1, -1):
        s = 0.0
        for i in range(j + 1, nsing):
            s += R[i][j] * wa[i]
        wa[j] = (wa[j] - s) / sdiag[j]
    out = [0.0] * n
    for j in range(n):
        out[ipvt[j]] = wa[j]
    return out, sdiag
