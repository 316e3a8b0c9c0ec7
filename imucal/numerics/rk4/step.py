"""One classic RK4 step of ``dq/dt = 1/2 q (x) (0, w(t))`` (method.md M5), in closed form.

The step is linear in ``q``: ``q_(n+1) = q_n (x) P_n``, with ``P_n`` built from the rates at
the step's start, middle and end only. With the thesis's half-step rate (the mean of the two
samples) the four RK4 stages collapse to a closed form (:func:`rk4_raw`), about a third of the
arithmetic of the stages written out.
"""

from __future__ import annotations

import numpy as np

from imucal.numerics.rk4.hamilton import Quat, Vec


def rk4_raw(w0: Vec, w1: Vec, h: np.ndarray, h2: np.ndarray | None = None) -> Quat:
    """Unnormalised RK4 step ``P`` for rates ``w0`` at the start and ``w1`` at the end.

    With ``a = w0/2``, ``c = w1/2``, the half-step rate ``m = (a + c)/2`` and ``A = 1/2 (0, w)``
    the stages are ``k1 = A1``, ``k2 = (1 + h/2 k1) A2``, ``k3 = (1 + h/2 k2) A2``,
    ``k4 = (1 + h k3) A4`` (each divided by ``q``) and ``P = 1 + h/6 (k1 + 2 k2 + 2 k3 + k4)``.
    Written out with ``(0, u)(0, v) = (-u.v, u x v)`` and ``m x m = 0`` they collapse to

        ``P = (1 - e/2 + e h^2 (w0.w1)/96,  h/4 (1 - e/6) s + h^2/24 (1 - e/4) (w0 x w1))``

    with ``s = w0 + w1`` and ``e = h^2 |s|^2 / 16`` (``= h^2 |m|^2``). For a constant rate this
    is the Taylor series of ``exp(h w / 2)`` to fourth order. A step with ``h = 0`` is exactly
    the identity, which is how padding is made harmless. ``h2`` is ``h * h`` if precomputed.
    """
    x0, y0, z0 = w0
    x1, y1, z1 = w1
    if h2 is None:
        h2 = h * h
    sx = x0 + x1
    sy = y0 + y1
    sz = z0 + z1
    cx = y0 * z1
    cx -= z0 * y1
    cy = z0 * x1
    cy -= x0 * z1
    cz = x0 * y1
    cz -= y0 * x1
    d = x0 * x1
    d += y0 * y1
    d += z0 * z1
    e = sx * sx
    e += sy * sy
    e += sz * sz
    e *= h2
    e *= 1.0 / 16.0
    d *= h2
    d *= e
    d *= 1.0 / 96.0
    pw = e * -0.5
    pw += 1.0
    pw += d
    al = e * (-1.0 / 6.0)
    al += 1.0
    al *= h
    al *= 0.25
    be = e * -0.25
    be += 1.0
    be *= h2
    be *= 1.0 / 24.0
    sx *= al
    cx *= be
    sx += cx
    sy *= al
    cy *= be
    sy += cy
    sz *= al
    cz *= be
    sz += cz
    return pw, sx, sy, sz


def rk4_steps(w0: Vec, w1: Vec, dt: np.ndarray) -> Quat:
    """``P_n`` (normalised) for steps with body rate ``w0`` at the start, ``w1`` at the end.

    ``w0``, ``w1`` are tuples of three component arrays (...), ``dt`` (...); see
    :func:`rk4_raw` for the closed form. The rate at the half step is the mean of the two
    samples (the thesis's choice).
    """
    pw, px, py, pz = rk4_raw(tuple(np.asarray(c, float) for c in w0),
                             tuple(np.asarray(c, float) for c in w1), np.asarray(dt, float))
    n = np.sqrt(pw * pw + px * px + py * py + pz * pz)
    return (pw / n, px / n, py / n, pz / n)


def rk4_step_quaternions(w0: np.ndarray, w1: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """:func:`rk4_steps` on (..., 3) rate arrays, as a (..., 4) array."""
    return np.stack(rk4_steps(tuple(np.moveaxis(w0, -1, 0)), tuple(np.moveaxis(w1, -1, 0)), dt),
                    axis=-1)
