"""Orientation from the gyroscope: classic RK4 on quaternions (method.md M5), vectorised.

For ``dq/dt = 1/2 q (x) W(t)`` (W the pure quaternion of the body rate) one RK4 step is linear
in ``q``: ``q_(n+1) = q_n (x) P_n``, with ``P_n`` a quaternion built from the rates at the step's
start, middle and end only. Renormalising after every step equals normalising each ``P_n``,
because ``|q (x) P| = |q| |P|``. So a whole transition is the ordered product
``P_0 (x) P_1 (x) ... (x) P_(L-1)``: every ``P_n`` of every transition is built in one vector
operation, and the products are reduced pairwise, in ``log2(L)`` vector operations, for all
transitions at once (no per-sample Python loop; linear work in the number of samples).

Quaternions are handled here as four separate component arrays (w, x, y, z): the hot loop
then runs on contiguous arrays without stacking or copying.
"""

from __future__ import annotations

import numpy as np

Vec = tuple[np.ndarray, np.ndarray, np.ndarray]
Quat = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def _dot(u: Vec, v: Vec) -> np.ndarray:
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


def _cross(u: Vec, v: Vec) -> Vec:
    return (u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0])


def _mul(p: Quat, q: Quat) -> Quat:
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    return (pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw)


def rk4_steps(w0: Vec, w1: Vec, dt: np.ndarray) -> Quat:
    """``P_n`` (normalised) for steps with body rate ``w0`` at the start, ``w1`` at the end.

    ``w0``, ``w1`` are tuples of three component arrays (...), ``dt`` (...). The rate at the
    half step is the mean of the two samples (the thesis's choice), so with ``A = 1/2 (0, w)``
    the stages are
    ``k1 = A1``, ``k2 = (1 + h/2 k1) A2``, ``k3 = (1 + h/2 k2) A2``, ``k4 = (1 + h k3) A4``
    (each divided by ``q``) and ``P = 1 + h/6 (k1 + 2 k2 + 2 k3 + k4)``. Products of pure
    quaternions are written out: ``(0, u)(0, v) = (-u.v, u x v)``. A step with ``dt = 0`` is the
    identity, which is how padding is made harmless.
    """
    a = (0.5 * w0[0], 0.5 * w0[1], 0.5 * w0[2])
    c = (0.5 * w1[0], 0.5 * w1[1], 0.5 * w1[2])
    m = (0.5 * (a[0] + c[0]), 0.5 * (a[1] + c[1]), 0.5 * (a[2] + c[2]))
    h = dt
    hh = 0.5 * h
    # k2 = A2 + h/2 A1 A2
    am = _cross(a, m)
    s2 = -hh * _dot(a, m)
    v2 = (m[0] + hh * am[0], m[1] + hh * am[1], m[2] + hh * am[2])
    # k3 = A2 + h/2 k2 A2, with k2 A2 = (-v2.m, s2 m + v2 x m)
    v2m = _cross(v2, m)
    s3 = -hh * _dot(v2, m)
    v3 = tuple(m[i] + hh * (s2 * m[i] + v2m[i]) for i in range(3))
    # k4 = A4 + h k3 A4, with k3 A4 = (-v3.c, s3 c + v3 x c)
    v3c = _cross(v3, c)
    s4 = -h * _dot(v3, c)
    v4 = tuple(c[i] + h * (s3 * c[i] + v3c[i]) for i in range(3))
    h6 = h / 6.0
    pw = 1.0 + h6 * (2.0 * s2 + 2.0 * s3 + s4)
    pv = [h6 * (a[i] + 2.0 * v2[i] + 2.0 * v3[i] + v4[i]) for i in range(3)]
    n = np.sqrt(pw * pw + pv[0] * pv[0] + pv[1] * pv[1] + pv[2] * pv[2])
    return (pw / n, pv[0] / n, pv[1] / n, pv[2] / n)


def ordered_product_soa(P: Quat) -> Quat:
    """``P[..., 0] (x) P[..., 1] (x) ...`` along the last axis, by pairwise reduction.

    Products of unit quaternions stay unit to rounding, so only the result is renormalised.
    """
    P = tuple(np.asarray(x) for x in P)
    while P[0].shape[-1] > 1:
        if P[0].shape[-1] % 2:
            pad = P[0].shape[:-1] + (1,)
            P = (np.concatenate([P[0], np.ones(pad)], axis=-1),
                 *(np.concatenate([x, np.zeros(pad)], axis=-1) for x in P[1:]))
        P = _mul(tuple(x[..., 0::2] for x in P), tuple(x[..., 1::2] for x in P))
    out = np.stack([x[..., 0] for x in P], axis=-1)
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def rk4_step_quaternions(w0: np.ndarray, w1: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """:func:`rk4_steps` on (..., 3) rate arrays, as a (..., 4) array."""
    return np.stack(rk4_steps(tuple(np.moveaxis(w0, -1, 0)), tuple(np.moveaxis(w1, -1, 0)), dt),
                    axis=-1)


def ordered_product(P: np.ndarray) -> np.ndarray:
    """Ordered product of (..., L, 4) quaternions along axis -2."""
    return ordered_product_soa(tuple(np.moveaxis(P, -1, 0)))


def padded_steps(t: np.ndarray, starts: np.ndarray, ends: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Sample indices (K, L) of each transition's steps and their ``dt`` (K, L), padded with
    ``dt = 0`` (identity steps) to the longest transition."""
    starts = np.asarray(starts, np.int64)
    n_steps = np.asarray(ends, np.int64) - starts
    L = int(max(n_steps.max(), 1)) if len(n_steps) else 1
    j = np.arange(L)
    valid = j[None, :] < n_steps[:, None]
    i0 = np.minimum(starts[:, None] + j[None, :], len(t) - 2)
    dt = np.where(valid, t[i0 + 1] - t[i0], 0.0)
    return i0, dt


def integrate_transitions(w: np.ndarray, t: np.ndarray, starts: np.ndarray, ends: np.ndarray
                          ) -> np.ndarray:
    """Body rotation over each interval ``[t[starts[k]], t[ends[k]]]`` from q = identity.

    ``w`` (M, 3) calibrated rates in rad/s at times ``t`` (M,); transition k takes
    ``ends[k] - starts[k]`` RK4 steps on the real timestamps. Returns (K, 4) quaternions.
    """
    if len(starts) == 0:
        return np.zeros((0, 4))
    i0, dt = padded_steps(t, starts, ends)
    wc = tuple(np.ascontiguousarray(w[:, i]) for i in range(3))
    return ordered_product_soa(rk4_steps(tuple(x[i0] for x in wc),
                                         tuple(x[i0 + 1] for x in wc), dt))
