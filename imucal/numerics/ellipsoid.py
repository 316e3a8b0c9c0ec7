"""Points on an ellipsoid: ``|G (x - c)| = 1`` with ``G`` symmetric positive definite.

Two fits, no sensor words: a closed-form algebraic fit of the general quadric (the start, from
any unit and any centre: no hand-set guess), and the maximum-likelihood refinement of ``G`` and
``c`` with its covariance. Both work on the points centred and scaled to unit RMS radius, so a
field in counts (thousands) and one in tesla (1e-5) condition the same.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from imucal.numerics.block_jackknife import design_effect_cov

# The 6 free entries of a symmetric 3x3 matrix, in the parameter vector's order.
SYM_INDEX = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
# Residual evaluations the refinement may take: a well-posed fit converges in under 10; points
# near a plane or a cone (a half of a recording, a partial coverage) let the ellipsoid stretch
# without end, and hundreds of steps would only sharpen a fit the data do not determine.
MAX_NFEV = 200
# ... and each stage of the robust start (a start: near is enough), on at most ROBUST_POINTS
# points evenly spread in the sequence (scipy's robust losses take an SVD of the Jacobian each
# step: 0.1 s at 20 000 points).
ROBUST_NFEV = 60
ROBUST_POINTS = 5000


def sym_from_vec(v: np.ndarray) -> np.ndarray:
    """The symmetric matrix of the 6 entries ``(g11, g12, g13, g22, g23, g33)``."""
    g = np.empty((3, 3))
    for k, (i, j) in enumerate(SYM_INDEX):
        g[i, j] = g[j, i] = v[k]
    return g


def vec_from_sym(g: np.ndarray) -> np.ndarray:
    return np.array([g[i, j] for i, j in SYM_INDEX])


def _normalise(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    mu = x.mean(axis=0)
    s = float(np.sqrt(np.mean(np.sum((x - mu) ** 2, axis=1))))
    if not np.isfinite(s) or s <= 0:
        raise ValueError("the points do not spread: no ellipsoid to fit")
    return (x - mu) / s, mu, s


def _sym_sqrt(a: np.ndarray) -> np.ndarray:
    w, v = np.linalg.eigh(a)
    return (v * np.sqrt(w)) @ v.T


def algebraic_fit(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, str]:
    """Closed-form ``(G, c, how)`` with ``|G (x - c)| ~ 1``: the quadric ``x'Ax + 2b'x + d = 0``
    whose 10 coefficients (unit norm) least violate the points (the smallest right singular
    vector); when that quadric is no ellipsoid (a partial coverage can make a hyperboloid),
    the sphere fit ``|x - c|^2 = r^2`` (linear in ``c`` and ``r^2 - |c|^2``) instead
    (``how`` says which)."""
    xn, mu, s = _normalise(np.asarray(x, float))
    X, Y, Z = xn.T
    D = np.column_stack([X * X, Y * Y, Z * Z, 2 * X * Y, 2 * X * Z, 2 * Y * Z,
                         2 * X, 2 * Y, 2 * Z, np.ones(len(xn))])
    v = np.linalg.svd(D, full_matrices=False)[2][-1]
    A = np.array([[v[0], v[3], v[4]], [v[3], v[1], v[5]], [v[4], v[5], v[2]]])
    if np.trace(A) < 0:
        A, v = -A, -v
    how = "ellipsoid"
    ok = bool(np.all(np.linalg.eigvalsh(A) > 0))
    if ok:
        c = -np.linalg.solve(A, v[6:9])
        k = c @ A @ c - v[9]  # (x - c)' A (x - c) = k
        ok = k > 0
    if ok:
        G = _sym_sqrt(A / k)
    else:
        how = "sphere"
        S = np.column_stack([2 * xn, np.ones(len(xn))])
        sol = np.linalg.lstsq(S, np.sum(xn * xn, axis=1), rcond=None)[0]
        c = sol[:3]
        G = np.eye(3) / np.sqrt(sol[3] + c @ c)
    return G / s, mu + s * c, how


@dataclass(frozen=True)
class EllipsoidFit:
    """The least-squares ``G`` and ``c`` of ``|G (x - c)| - 1``: the parameters ``p = (g11,
    g12, g13, g22, g23, g33, c1, c2, c3)`` in the points' unit and their covariance ``cov``
    (9, 9): ``cov_white``, what independent residuals would give (``s^2 (J'J)^-1``, ``s^2``
    the residuals' variance with 9 degrees of freedom taken), times ``deff``, the design
    effect of the residuals' correlation along the points' order, measured by a block
    jackknife of ``block`` points (:mod:`imucal.numerics.block_jackknife`; about 1 for
    independent residuals); the residuals' RMS (a fraction of the radius) and the points
    used."""

    G: np.ndarray
    c: np.ndarray
    cov: np.ndarray
    rms: float
    n: int
    start: str  # how the algebraic start was made: "ellipsoid" or "sphere"
    cond: float  # condition number of the Jacobian (normalised parameters)
    model: str = "ellipsoid"  # "sphere": G held at I / r, only c and r fitted
    cov_white: np.ndarray | None = None
    deff: float = 1.0
    block: int = 1

    @property
    def params(self) -> np.ndarray:
        return np.r_[vec_from_sym(self.G), self.c]

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """``|G (x - c)| - 1`` for (N, 3) points: a fraction of the radius."""
        return np.linalg.norm((x - self.c) @ self.G, axis=1) - 1.0


def _res_jac(p: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    G = sym_from_vec(p[:6])
    d = x - p[6:9]
    y = d @ G  # G symmetric: rows are G d_i
    n = np.linalg.norm(y, axis=1)
    J = np.empty((len(x), 9))
    for k, (i, j) in enumerate(SYM_INDEX):
        J[:, k] = (y[:, i] * d[:, j] + (y[:, j] * d[:, i] if i != j else 0.0)) / n
    J[:, 6:9] = -(y @ G) / n[:, None]
    return n - 1.0, J


def ml_fit(x: np.ndarray, G0: np.ndarray, c0: np.ndarray, start: str = "given",
           refine: bool = True) -> EllipsoidFit:
    """Refine ``G``, ``c`` by least squares on ``|G (x - c)| - 1`` over every point (Gauss–
    Newton/trust region, analytic Jacobian), starting from ``(G0, c0)``; ``refine=False``
    keeps ``(G0, c0)`` and only measures it."""
    x = np.asarray(x, float)
    xn, mu, s = _normalise(x)
    p = np.r_[vec_from_sym(G0 * s), (c0 - mu) / s]
    if refine:
        from scipy.optimize import least_squares  # where a fit runs

        p = least_squares(lambda q: _res_jac(q, xn)[0], p, jac=lambda q: _res_jac(q, xn)[1],
                          method="lm", x_scale="jac", max_nfev=MAX_NFEV).x
    r, J = _res_jac(p, xn)
    # method.md §9: the residual is slow on real data, its rows not independent
    cov_n, white_n, deff, block = design_effect_cov(J, r, len(xn) - 9)
    # back to the points' unit: G = G_n / s, c = mu + s c_n (linear in the parameters)
    unit = np.r_[np.full(6, 1.0 / s), np.full(3, s)]
    scale = np.outer(unit, unit)
    sv = np.linalg.svd(J, compute_uv=False)
    return EllipsoidFit(G=sym_from_vec(p[:6]) / s, c=mu + s * p[6:9], cov=cov_n * scale,
                        rms=float(np.sqrt(np.mean(r * r))), n=len(xn), start=start,
                        cond=float(sv[0] / max(sv[-1], 1e-300)),
                        cov_white=white_n * scale, deff=deff, block=block)


def fit_ellipsoid(x: np.ndarray, robust: bool = False) -> EllipsoidFit:
    """The algebraic start, then the maximum-likelihood fit; ``robust``: the start first
    refined with a Cauchy loss whose scale narrows from 10 % to 1 % of the radius, so that a
    minority of points off the ellipsoid (a disturbed part) pulls it little, and kept (its
    covariance is the plain fit's formula at that point: a guide, not a standard error)."""
    G0, c0, how = algebraic_fit(x)
    if robust:
        x = np.asarray(x, float)
        G0, c0 = _cauchy(x[::max(1, -(-len(x) // ROBUST_POINTS))], G0, c0)
    return ml_fit(x, G0, c0, how, refine=not robust)


def _cauchy(x: np.ndarray, G0: np.ndarray, c0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    xn, mu, s = _normalise(x)
    p = np.r_[vec_from_sym(G0 * s), (c0 - mu) / s]
    for scale in (0.1, 0.03, 0.01):
        from scipy.optimize import least_squares  # where a fit runs

        p = least_squares(lambda q: _res_jac(q, xn)[0], p, jac=lambda q: _res_jac(q, xn)[1],
                          loss="cauchy", f_scale=scale, max_nfev=ROBUST_NFEV).x
    return sym_from_vec(p[:6]) / s, mu + s * p[6:9]


def is_ellipsoid(G: np.ndarray) -> bool:
    """Whether ``G`` is finite and positive definite (a closed surface, not a hyperboloid or a
    cylinder that points near a plane or a line allow)."""
    return bool(np.all(np.isfinite(G)) and np.all(np.linalg.eigvalsh(G) > 0))


BIAS_DRAWS = 8  # simulated fits that measure the sphere fit's bias


def _sphere_res_jac(q: np.ndarray, xn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    d = xn - q[1:4]
    n = np.linalg.norm(d, axis=1)
    J = np.column_stack([-n / q[0] ** 2, -d / (n * q[0])[:, None]])
    return n / q[0] - 1.0, J


def _sphere_ml(xn: np.ndarray, q0: np.ndarray | None = None) -> np.ndarray:
    """``(r, c)`` of ``|x - c| = r`` by least squares on ``|x - c| / r - 1``, from the linear
    closed form (or ``q0``)."""
    if q0 is None:
        sol = np.linalg.lstsq(np.column_stack([2 * xn, np.ones(len(xn))]),
                              np.sum(xn * xn, axis=1), rcond=None)[0]
        q0 = np.r_[np.sqrt(max(sol[3] + sol[:3] @ sol[:3], 1e-12)), sol[:3]]
    from scipy.optimize import least_squares  # where a fit runs

    return least_squares(lambda v: _sphere_res_jac(v, xn)[0], q0,
                         jac=lambda v: _sphere_res_jac(v, xn)[1], method="lm",
                         max_nfev=MAX_NFEV).x


def sphere_fit(x: np.ndarray) -> EllipsoidFit:
    """``|x - c| = r``: the linear closed form refined by maximum likelihood (residual
    ``|x - c| / r - 1``), as an :class:`EllipsoidFit` with ``G = I / r``; its covariance is
    that of ``(r, c)`` carried to the 9 parameters (``g11 = g22 = g33 = 1 / r``, the rest 0):
    the shape is held, not estimated. For points that reach too few directions to determine
    an ellipsoid's 9 parameters. On a cap the geometric fit's centre has a second-order bias
    along the cap's axis, about 1.5 sigma^2 (per-axis noise sigma, the points' unit; measured
    on a 50-degree cap of radius 43: 2-3 standard errors at noise of 0.3 % of the radius): it
    is measured by fitting the fit's own points again with noise, and removed."""
    x = np.asarray(x, float)
    xn, mu, s = _normalise(x)
    q = _sphere_ml(xn)
    # The bias, measured: the same directions on the fitted sphere with the residuals'
    # noise, fitted again (a parametric bootstrap, fixed seed), their mean offset removed.
    d = xn - q[1:4]
    u = d / np.linalg.norm(d, axis=1, keepdims=True)
    sigma = q[0] * float(np.std(np.linalg.norm(d, axis=1) / q[0] - 1.0))
    rng = np.random.default_rng(0)
    sims = [_sphere_ml(q[1:4] + q[0] * u + rng.normal(0, sigma, u.shape), q)
            for _ in range(BIAS_DRAWS)]
    q = q - (np.mean(sims, axis=0) - q)
    r, J = _sphere_res_jac(q, xn)
    cov4, white4, deff, block = design_effect_cov(J, r, len(xn) - 4)  # as ml_fit's
    radius, c = q[0] * s, mu + s * q[1:4]
    T = np.zeros((9, 4))  # d(g11, g12, g13, g22, g23, g33, c) / d(r, c), the points' unit
    T[[0, 3, 5], 0] = -1.0 / radius ** 2
    T[6:9, 1:4] = np.eye(3)
    scale = np.diag([s, s, s, s])  # (r, c) normalised -> the points' unit
    cov = T @ scale @ cov4 @ scale @ T.T
    white = T @ scale @ white4 @ scale @ T.T
    sv = np.linalg.svd(J, compute_uv=False)
    return EllipsoidFit(G=np.eye(3) / radius, c=c, cov=cov, rms=float(np.sqrt(np.mean(r * r))),
                        n=len(xn), start="sphere", cond=float(sv[0] / max(sv[-1], 1e-300)),
                        model="sphere", cov_white=white, deff=deff, block=block)


def fibonacci_sphere(n: int) -> np.ndarray:
    """``n`` unit directions spread evenly over the sphere."""
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = np.pi * (1 + 5**0.5) * i
    rho = np.sqrt(1 - z * z)
    return np.column_stack([rho * np.cos(phi), rho * np.sin(phi), z])


def sphere_coverage(u: np.ndarray, angle_deg: float, n: int = 400
                    ) -> tuple[float, np.ndarray]:
    """The fraction of ``n`` even test directions within ``angle_deg`` of some unit vector of
    ``u`` (N, 3), and the test directions left uncovered (a chunk of ``u`` at a time)."""
    dirs = fibonacci_sphere(n)
    cos = np.cos(np.radians(angle_deg))
    near = np.zeros(n, bool)
    for a in range(0, len(u), 1 << 15):
        near |= (dirs @ u[a:a + (1 << 15)].T).max(axis=1) >= cos
    return float(near.mean()), dirs[~near]
