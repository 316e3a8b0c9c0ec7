"""The arithmetic of one sample and one step, compiled (numba): the affine rate model, one
classic RK4 step in closed form (method.md M5), the Hamilton product and the rotation matrix.

These are inlined into the loops of :mod:`.kernels` by LLVM. They carry no signatures, so the
same code compiles for complex numbers too (the complex-step Jacobian of ``bench/run.py``).
"""

from __future__ import annotations

from imucal.numerics.rk4.jit import jit


@jit()
def calibrated(w, n, M, b):  # pragma: no cover - compiled
    """``M (w[n] - b)`` (method.md M4) and ``w[n] - b``, as six scalars."""
    dx = w[n, 0] - b[0]
    dy = w[n, 1] - b[1]
    dz = w[n, 2] - b[2]
    cx = M[0, 0] * dx + M[0, 1] * dy + M[0, 2] * dz
    cy = M[1, 0] * dx + M[1, 1] * dy + M[1, 2] * dz
    cz = M[2, 0] * dx + M[2, 1] * dy + M[2, 2] * dz
    return cx, cy, cz, dx, dy, dz


@jit()
def rk4_step(x0, y0, z0, x1, y1, z1, h):  # pragma: no cover - compiled
    """Unnormalised RK4 step ``P`` of ``dq/dt = 1/2 q (x) (0, w(t))`` for rates ``w0`` at the
    start and ``w1`` at the end of a step of ``h`` (method.md M5): ``q_(n+1) = q_n (x) P``.

    With ``a = w0/2``, ``c = w1/2``, the half-step rate ``m = (a + c)/2`` (the thesis's choice)
    and ``A = 1/2 (0, w)`` the stages are ``k1 = A1``, ``k2 = (1 + h/2 k1) A2``,
    ``k3 = (1 + h/2 k2) A2``, ``k4 = (1 + h k3) A4`` (each divided by ``q``) and
    ``P = 1 + h/6 (k1 + 2 k2 + 2 k3 + k4)``. Written out with ``(0, u)(0, v) = (-u.v, u x v)``
    and ``m x m = 0`` they collapse to

        ``P = (1 - e/2 + e h^2 (w0.w1)/96,  h/4 (1 - e/6) s + h^2/24 (1 - e/4) (w0 x w1))``

    with ``s = w0 + w1`` and ``e = h^2 |s|^2 / 16`` (``= h^2 |m|^2``), about a third of the
    arithmetic of the stages. For a constant rate this is the Taylor series of ``exp(h w / 2)``
    to fourth order; a step with ``h = 0`` is exactly the identity.
    """
    h2 = h * h
    sx = x0 + x1
    sy = y0 + y1
    sz = z0 + z1
    cx = y0 * z1 - z0 * y1
    cy = z0 * x1 - x0 * z1
    cz = x0 * y1 - y0 * x1
    d = x0 * x1 + y0 * y1 + z0 * z1
    e = (sx * sx + sy * sy + sz * sz) * h2 * (1.0 / 16.0)
    pw = (e * -0.5 + 1.0) + d * h2 * e * (1.0 / 96.0)
    al = (e * (-1.0 / 6.0) + 1.0) * h * 0.25
    be = (e * -0.25 + 1.0) * h2 * (1.0 / 24.0)
    return pw, sx * al + cx * be, sy * al + cy * be, sz * al + cz * be


@jit()
def hamilton(qw, qx, qy, qz, pw, px, py, pz):  # pragma: no cover - compiled
    """The Hamilton product ``q (x) p``."""
    return (qw * pw - qx * px - qy * py - qz * pz,
            qw * px + qx * pw + qy * pz - qz * py,
            qw * py - qx * pz + qy * pw + qz * px,
            qw * pz + qx * py - qy * px + qz * pw)


@jit()
def rotation_matrix(qw, qx, qy, qz):  # pragma: no cover - compiled
    """The rotation matrix of ``q``, row-major as nine scalars; exact for a quaternion that is
    not quite unit (a product of RK4 steps is not)."""
    s = 2.0 / (qw * qw + qx * qx + qy * qy + qz * qz)
    xs = qx * s
    ys = qy * s
    zs = qz * s
    xy = qx * ys
    wz = qw * zs
    xz = qx * zs
    wy = qw * ys
    yz = qy * zs
    wx = qw * xs
    xx = qx * xs
    yy = qy * ys
    zz = qz * zs
    return (1.0 - (yy + zz), xy - wz, xz + wy,
            xy + wz, 1.0 - (xx + zz), yz - wx,
            xz - wy, yz + wx, 1.0 - (xx + yy))
