"""Where the accelerometer fit starts (method.md §3): the nominal frame it runs in, and a
closed-form linear ellipsoid fit of the still points, a better start than the prior where the
sensor is far from nominal (the thesis names LM's local minima)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from imucal.errors import ImucalError
from imucal.models import SensorModel, acc_T


@dataclass(frozen=True)
class Nominal:
    """The frame the fit runs in: ``a_n = (a_raw - offset) / scale`` has norm about 1.

    The Tikhonov prior ``theta_0`` (identity) means "the sensor is nominal"; in g or m/s^2
    that is the raw signal itself, in raw counts there is no nominal, so an isotropic sphere
    fit of the still points stands in for the datasheet's offset and sensitivity.
    """

    offset: np.ndarray
    scale: float
    how: str

    def to_nominal(self, raw: np.ndarray) -> np.ndarray:
        return (raw - self.offset) / self.scale


def to_raw_model(theta: np.ndarray, nominal: Nominal, g_out: float) -> SensorModel:
    """Back to raw units: ``a = g_out T K_n ((a_raw - c0)/s0 - b_n) = T K (a_raw - b)`` with
    ``K = K_n g_out / s0`` and ``b = c0 + s0 b_n``."""
    return SensorModel(T=acc_T(theta), K=theta[3:6] * (g_out / nominal.scale),
                       b=nominal.offset + nominal.scale * theta[6:9])


def sphere_fit(pts: np.ndarray) -> tuple[np.ndarray, float]:
    """Closed-form least-squares sphere: |p - c|^2 = r^2 is linear in (c, r^2 - |c|^2)."""
    A = np.hstack([2 * pts, np.ones((len(pts), 1))])
    rhs = np.einsum("ij,ij->i", pts, pts)
    sol, *_ = np.linalg.lstsq(A, rhs, rcond=None)
    c = sol[:3]
    r2 = sol[3] + c @ c
    return c, float(np.sqrt(r2)) if r2 > 0 else float("nan")


def ellipsoid_start(pts: np.ndarray) -> np.ndarray | None:
    """Closed-form start for M2: a linear ellipsoid fit of the still points (nominal frame).

    Fits the quadric ``x'Ax + d'x + e = 0`` by the smallest singular vector of its design
    matrix, reads the centre ``b = -A^-1 d / 2`` and ``M = A / (b'Ab - e)`` so that
    ``(x-b)' M (x-b) = 1``. Since ``M = (TK)'(TK)`` with ``TK`` upper triangular with a positive
    diagonal, ``TK`` is the transposed Cholesky factor of ``M`` and gives T, K directly.
    Returns ``None`` where the points do not determine an ellipsoid (too few orientations).
    """
    if len(pts) < 9:
        return None
    mu = pts.mean(axis=0)
    sc = float(np.std(pts - mu)) or 1.0
    x, y, z = ((pts - mu) / sc).T
    D = np.column_stack([x * x, y * y, z * z, 2 * x * y, 2 * x * z, 2 * y * z, x, y, z,
                         np.ones_like(x)])
    _, s, vt = np.linalg.svd(D, full_matrices=False)
    if s[-1] > 1e-6 * s[0] and s[-2] < 1e-9 * s[0]:
        return None
    if s[-2] < 1e-8 * s[0]:  # a family of quadrics fits: the poses do not span enough directions
        return None
    p = vt[-1]
    A = np.array([[p[0], p[3], p[4]], [p[3], p[1], p[5]], [p[4], p[5], p[2]]])
    d = p[6:9]
    e = p[9]
    try:
        c = -0.5 * np.linalg.solve(A, d)
    except np.linalg.LinAlgError:
        return None
    k = c @ A @ c - e
    if k == 0:
        return None
    M = A / k
    try:
        L = np.linalg.cholesky(M)  # M = L L', so TK = L' (scaled back below)
    except np.linalg.LinAlgError:
        return None
    U = L.T / sc
    b = mu + sc * c
    s_x, s_y, s_z = U[0, 0], U[1, 1], U[2, 2]
    theta = np.array([-U[0, 1] / s_y, U[0, 2] / s_z, -U[1, 2] / s_z, s_x, s_y, s_z, *b])
    return theta if np.all(np.isfinite(theta)) else None


def make_nominal(pts: np.ndarray, acc_unit: str, g_in: float) -> Nominal:
    """The nominal frame of the fit (see :class:`Nominal`); ``g_in`` is |g| in input units."""
    if acc_unit == "counts":
        c, r = sphere_fit(pts)
        if not np.isfinite(r) or r <= 0:
            raise ImucalError("cannot find a nominal offset and sensitivity for raw counts: the "
                              "still poses do not span enough directions",
                              source="accelerometer", field="static blocks")
        return Nominal(offset=c, scale=r, how="sphere fit of the still points (raw counts)")
    return Nominal(offset=np.zeros(3), scale=g_in, how=f"input unit {acc_unit}, |g| = {g_in:g}")
