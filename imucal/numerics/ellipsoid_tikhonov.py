"""An ellipsoid fit held towards a sphere: ``|G (x - c)| = 1`` with a Tikhonov term on the
shape, ``lambda`` from the L-curve (method.md §9, M8r). No sensor words.

For points that reach only part of the sphere of directions the shape of the ellipsoid is
weakly determined, or not at all, and the plain fit stretches it to follow the noise. Here:

- the data residual is in the points' unit, ``(|G (x - c)| - 1) / g`` with ``g = tr(G) / 3``
  (about the inverse radius): the residual relative to the radius (``ellipsoid.ml_fit``'s)
  falls towards zero for an ever larger or flatter quadric, an escape that fits a patch of
  the sphere below the noise; in the points' unit it cannot;
- the prior term ``lambda |G / g - I|_F^2`` pulls the shape (``G``'s deviation from a scaled
  identity) towards a sphere; the radius and the centre are free;
- the cost is ``mean(r^2) + lambda eta^2``, in the points scaled to unit RMS radius, so that
  ``lambda`` means the same whatever their number and unit;
- ``lambda`` is swept from large to small, each fit continued from the previous one, so the
  branch followed is the one that starts at the sphere; the sweep stops where the fit stops
  being a physical ellipsoid (not positive definite, or axes more than MAX_AXIS_RATIO apart):
  below, the fit has escaped to a degenerate quadric (measured on 5-pose synthetic sessions:
  soft iron 0.35-0.42 off, hard iron 2 field units off);
- the corner: :func:`imucal.numerics.lcurve.lcurve_corner` on the curve past its start (see
  :func:`choose_corner`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from imucal.numerics.block_jackknife import design_effect_cov
from imucal.numerics.ellipsoid import EllipsoidFit, _normalise, _res_jac, sym_from_vec, vec_from_sym
from imucal.numerics.lcurve import lcurve_corner

# 34 values, three a decade, as the accelerometer's grid: 1e-10 is far below where any shape
# moves (the full sphere's fit moves from 1e-5), 10 is the sphere to 1e-4 of the shape.
LAMBDAS = np.logspace(-10, 1, 34)
# A real soft iron bends the field by some per cent, rarely beyond 30 %: axes 3 times apart
# are no magnetometer's, they are the fit escaping to a degenerate quadric.
MAX_AXIS_RATIO = 3.0
# The fit is the unregularised one while rho and eta stay within this (the accelerometer's
# LCurve.SAME_FIT) of the smallest lambda's.
SAME_FIT = 1e-3
# The curve has left its start once eta is this fraction of the smallest lambda's: every
# L-curve bends where it starts to move, a bend that is no corner between two arms (taken
# there, the halves of 5-pose synthetic sessions chose lambda 2e-8, the plain fit, 25 % held
# out, where the corner past it gave 2.6 %).
ONSET = 0.9
# A bend of the curve (log rho, log eta; natural logs) less sharp than this is no corner:
# the corners taken on the halves of 5-pose synthetic sessions bent by 0.9-2.7, a cap of
# directions whose curve is one straight fall of eta at constant rho by 0.005 at the most.
MIN_CURVATURE = 0.1
# Without a corner the unregularised fit is kept only where the data alone determine its
# shape to this (1 % of the field; a half of BROAD's trial 02 reaching a band of 26 % of the
# directions had a flat stretch at a shape 0.44 from a sphere, 23 % held out).
SHAPE_STD = 0.01
MAX_NFEV = 200
# The sweep runs on at most this many points evenly spread in the sequence; the fit at the
# corner on all of them, continued from the sweep's.
SWEEP_POINTS = 20_000
# the Frobenius norm of a symmetric matrix from its 6 entries (g11, g12, g13, g22, g23, g33)
_FROB = np.array([1.0, np.sqrt(2), np.sqrt(2), 1.0, np.sqrt(2), 1.0])
_BASIS = [sym_from_vec(e) for e in np.eye(6)]
_DG = np.array([1.0, 0, 0, 1.0, 0, 1.0, 0, 0, 0]) / 3.0  # d g / d p


def raw_res_jac(p: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(|G (x - c)| - 1) / g`` and its Jacobian (n, 9), ``g = tr(G) / 3``: the norm residual
    in the points' unit."""
    r, J = _res_jac(p, x)
    g = (p[0] + p[3] + p[5]) / 3.0
    return r / g, (J - np.outer(r, _DG)) / g


def shape_penalty(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``G / g - I`` (its 6 entries weighted so that their norm is the Frobenius norm) and its
    Jacobian (6, 9): the shape's deviation from a sphere, blind to the radius and centre."""
    G = sym_from_vec(p[:6])
    g = np.trace(G) / 3.0
    r = _FROB * vec_from_sym(G / g - np.eye(3))
    J = np.zeros((6, 9))
    for k, E in enumerate(_BASIS):
        J[:, k] = _FROB * vec_from_sym(E / g - G * np.trace(E) / (3.0 * g * g))
    return r, J


def physical(p: np.ndarray) -> bool:
    """Positive definite with axes at most MAX_AXIS_RATIO apart."""
    w = np.linalg.eigvalsh(sym_from_vec(p[:6]))
    return bool(np.all(np.isfinite(w)) and w[0] > 0 and w[-1] <= MAX_AXIS_RATIO * w[0])


def _solve(xn: np.ndarray, lam: float, p0: np.ndarray) -> np.ndarray:
    from scipy.optimize import least_squares  # where a fit runs

    a, sl = 1.0 / np.sqrt(len(xn)), np.sqrt(lam)

    def fun(q: np.ndarray) -> np.ndarray:
        return np.r_[a * raw_res_jac(q, xn)[0], sl * shape_penalty(q)[0]]

    def jac(q: np.ndarray) -> np.ndarray:
        return np.vstack([a * raw_res_jac(q, xn)[1], sl * shape_penalty(q)[1]])

    return least_squares(fun, p0, jac=jac, method="lm", x_scale="jac", max_nfev=MAX_NFEV).x


def choose_corner(lambdas: np.ndarray, rho: np.ndarray, eta: np.ndarray, cut: bool = False,
                  determined: bool = True) -> tuple[int, np.ndarray, int]:
    """``(corner, curvature, same_fit_until)``: the L-curve's corner past its start (the
    first lambda whose eta is ONSET of the smallest lambda's, and past the stretch where the
    fit is the smallest lambda's), by :func:`lcurve_corner`; where the curvature is largest at
    the first point past the start, or bends less than MIN_CURVATURE, the curve has no corner
    beyond it: where it ends on a stretch that gives the unregularised fit and that fit's
    shape is ``determined`` by the data alone, the corner is the smallest lambda (the
    stretch's fits differ by up to 0.1 % of eta, 0.3 standard errors of the full coverage's
    soft iron: the smallest is the plain fit); where it does not (the shape still moving at
    the grid's smallest lambda), or was ``cut`` (below its smallest lambda the fit escapes,
    :func:`physical`), or the shape is not determined, the corner is the largest lambda (the
    sphere's end: a curve that only bends away from the sphere, as x-io's recording's does,
    or falls straight, as a cap's, has no balance to strike)."""
    rho, eta = np.asarray(rho, float), np.asarray(eta, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        same = (np.abs(rho / rho[0] - 1) <= SAME_FIT) & (np.abs(eta / eta[0] - 1) <= SAME_FIT)
    until = int(np.argmin(same) - 1) if not same.all() else len(same) - 1
    moved = eta <= ONSET * eta[0]
    start = max(until + 1, int(np.argmax(moved)) if moved.any() else len(eta))
    curv = np.zeros(len(eta))
    if len(eta) - start >= 3:
        k, c = lcurve_corner(np.asarray(lambdas[start:], float), rho[start:], eta[start:])
        curv[start:] = c
        if k > 1 and c[k] >= MIN_CURVATURE:
            return start + k, curv, until
    plain = until >= 1 and not cut and determined
    return (0 if plain else len(eta) - 1), curv, until


@dataclass(frozen=True)
class RegularisedFit:
    """The fit at the corner (``fit``: its ``cov`` the regularised estimator's, ``H^-1 J'J
    H^-1`` times the design effect, ``H = J'J + n lambda P'P``), ``cov_data`` the data-alone
    covariance of the same parameters (``(J'J)^-1`` through the SVD, times the design effect:
    past any limit in a direction the data do not see), and the L-curve: ``lambdas`` (those
    whose fit is a physical ellipsoid), ``rho`` (RMS norm residual, the points' unit),
    ``eta`` (``|G / g - I|_F``), ``params`` (L, 9) the fits in the points' unit, ``corner``,
    ``curvature``, ``same_fit_until``."""

    fit: EllipsoidFit
    cov_data: np.ndarray
    lam: float
    lambdas: np.ndarray
    rho: np.ndarray
    eta: np.ndarray
    params: np.ndarray
    corner: int
    curvature: np.ndarray
    same_fit_until: int


def shape_determined(p: np.ndarray, x: np.ndarray) -> bool:
    """Whether the data alone determine the shape ``G / g`` of the fit ``p`` to ``x`` (the
    points' unit): each entry's data-alone standard error (``(J'J)^-1 s^2 deff``, M8s's
    design effect) at most SHAPE_STD."""
    r, J = raw_res_jac(p, x)
    _, _, deff, _ = design_effect_cov(J, r, len(x) - 9)
    d = 1.0 / np.maximum(np.linalg.norm(J, axis=0), 1e-300)
    _, sv, Vt = np.linalg.svd(J * d, full_matrices=False)
    A = (Vt.T / np.maximum(sv, sv[0] * 1e-14)) * d[:, None]
    P = shape_penalty(p)[1] / _FROB[:, None]
    s2 = float(r @ r) / max(len(x) - 9, 1)
    var = deff * s2 * np.sum((P @ A) ** 2, axis=1)
    return bool(np.all(np.sqrt(var) <= SHAPE_STD))


def _sphere_start(xn: np.ndarray) -> np.ndarray:
    sol = np.linalg.lstsq(np.column_stack([2 * xn, np.ones(len(xn))]),
                          np.sum(xn * xn, axis=1), rcond=None)[0]
    r2 = max(float(sol[3] + sol[:3] @ sol[:3]), 1e-12)
    return np.r_[vec_from_sym(np.eye(3) / np.sqrt(r2)), sol[:3]]


def regularised_fit(x: np.ndarray, lambdas: np.ndarray = LAMBDAS) -> RegularisedFit:
    """The sweep from the largest lambda down (from the sphere's closed form), the corner,
    and the fit there with its covariances (method.md §9, M8r). Raises ValueError when not
    even the largest lambda gives a physical ellipsoid."""
    x = np.asarray(x, float)
    xn, mu, s = _normalise(x)
    xs = xn[::max(1, -(-len(xn) // SWEEP_POINTS))]
    lams = np.sort(np.asarray(lambdas, float))[::-1]
    p = _sphere_start(xs)
    kept: list[tuple[float, np.ndarray]] = []
    for lam in lams:
        p = _solve(xs, float(lam), p)
        if not physical(p):
            break
        kept.append((float(lam), p.copy()))
    if not kept:
        raise ValueError("no physical ellipsoid even at the largest lambda")
    kept.reverse()
    lam_k = np.array([k[0] for k in kept])
    ps = np.array([k[1] for k in kept])
    rho = np.array([np.sqrt(np.mean(raw_res_jac(q, xs)[0] ** 2)) for q in ps])
    eta = np.array([np.linalg.norm(shape_penalty(q)[0]) for q in ps])
    cut = len(kept) < len(lams)
    corner, curv, until = choose_corner(lam_k, rho, eta, cut, shape_determined(ps[0], xs))
    q, lam = ps[corner], float(lam_k[corner])
    if len(xs) < len(xn):  # the corner's fit on every point
        full = _solve(xn, lam, q)
        q = full if physical(full) else q
    r, J = raw_res_jac(q, xn)
    n = len(xn)
    # method.md M8s: the residual's correlation along the points' order, one factor
    _, white, deff, block = design_effect_cov(J, r, n - 9)
    s2 = float(r @ r) / max(n - 9, 1)
    d = 1.0 / np.maximum(np.linalg.norm(J, axis=0), 1e-300)  # unit columns, as elsewhere
    Js = J * d
    U, sv, Vt = np.linalg.svd(Js, full_matrices=False)
    A = Vt.T / np.maximum(sv, sv[0] * 1e-14)
    cov_data = deff * s2 * (A @ A.T) * np.outer(d, d)
    P = shape_penalty(q)[1] * d
    Hs = Js.T @ Js + n * lam * P.T @ P
    Hi = np.linalg.pinv(Hs)
    cov_reg = deff * s2 * (Hi @ (Js.T @ Js) @ Hi) * np.outer(d, d)
    unit = np.r_[np.full(6, 1.0 / s), np.full(3, s)]
    scale = np.outer(unit, unit)
    rel = _res_jac(q, xn)[0]
    fit = EllipsoidFit(G=sym_from_vec(q[:6]) / s, c=mu + s * q[6:9], cov=cov_reg * scale,
                       rms=float(np.sqrt(np.mean(rel * rel))), n=n, start="sphere",
                       cond=float(sv[0] / max(sv[-1], 1e-300)), model="regularised",
                       cov_white=white * scale, deff=deff, block=block)
    params = np.column_stack([ps[:, :6] / s, mu + s * ps[:, 6:9]])
    return RegularisedFit(fit=fit, cov_data=cov_data * scale, lam=lam, lambdas=lam_k,
                          rho=rho * s, eta=eta, params=params, corner=corner, curvature=curv,
                          same_fit_until=until)
