"""Orientation from the gyroscope: classic RK4 on quaternions (method.md M5), vectorised.

For ``dq/dt = 1/2 q (x) W(t)`` (W the pure quaternion of the body rate) one RK4 step is linear
in ``q``: ``q_(n+1) = q_n (x) P_n``, with ``P_n`` a quaternion built from the rates at the step's
start, middle and end only. Renormalising after every step equals normalising each ``P_n``,
because ``|q (x) P| = |q| |P|``. So a whole transition is the ordered product
``P_0 (x) P_1 (x) ... (x) P_(L-1)``: every ``P_n`` of every transition is built in one vector
operation, and the products are reduced pairwise, in ``log2(L)`` vector operations, for all
transitions at once (no per-sample Python loop; linear work in the number of samples).
"""

from __future__ import annotations

import numpy as np

from .quaternion import multiply, normalize


def _pure(w: np.ndarray) -> np.ndarray:
    """The pure quaternion ``(0, w/2)``: RK4's A = 1/2 W."""
    return np.concatenate([np.zeros(w.shape[:-1] + (1,)), 0.5 * w], axis=-1)


def rk4_step_quaternions(w0: np.ndarray, w1: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """``P_n`` for steps with body rate ``w0`` at the start and ``w1`` at the end (M5).

    The rate at the half step is the mean of the two samples (the thesis's choice), so
    ``A2 = A3`` and, with ``k1 = q A1``, ``k2 = q (1 + h/2 A1) A2``,
    ``k3 = q (1 + h/2 A2 + h^2/4 A1 A2) A2`` and ``k4 = q (1 + h k3/q) A4``,
    ``P = 1 + h/6 (k1 + 2 k2 + 2 k3 + k4) / q``. Returned normalised.
    """
    h = dt[..., None]
    A1 = _pure(w0)
    A2 = _pure(0.5 * (w0 + w1))
    A4 = _pure(w1)
    one = np.zeros(A1.shape)
    one[..., 0] = 1.0
    k1 = A1
    k2 = multiply(one + 0.5 * h * k1, A2)
    k3 = multiply(one + 0.5 * h * k2, A2)
    k4 = multiply(one + h * k3, A4)
    return normalize(one + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4))


def ordered_product(P: np.ndarray) -> np.ndarray:
    """``P[..., 0, :] (x) P[..., 1, :] (x) ...`` along axis -2, by pairwise reduction."""
    while P.shape[-2] > 1:
        if P.shape[-2] % 2:
            ident = np.zeros(P.shape[:-2] + (1, 4))
            ident[..., 0] = 1.0
            P = np.concatenate([P, ident], axis=-2)
        P = normalize(multiply(P[..., 0::2, :], P[..., 1::2, :]))
    return P[..., 0, :]


def integrate_transitions(w: np.ndarray, t: np.ndarray, starts: np.ndarray, ends: np.ndarray
                          ) -> np.ndarray:
    """Body rotation over each interval ``[t[starts[k]], t[ends[k]]]`` from q = identity.

    ``w`` (M, 3) calibrated rates in rad/s at times ``t`` (M,); the interval of transition k
    runs over the samples ``starts[k] .. ends[k]`` (inclusive), i.e. ``ends[k] - starts[k]``
    RK4 steps on the real timestamps. Returns (K, 4) quaternions. The steps of all transitions
    are padded to the longest with identity steps, which leave the product unchanged.
    """
    starts = np.asarray(starts, np.int64)
    ends = np.asarray(ends, np.int64)
    n_steps = ends - starts
    K = len(starts)
    if K == 0:
        return np.zeros((0, 4))
    L = int(max(n_steps.max(), 1))
    j = np.arange(L)
    valid = j[None, :] < n_steps[:, None]
    i0 = np.minimum(starts[:, None] + j[None, :], len(t) - 2)
    P = np.zeros((K, L, 4))
    P[..., 0] = 1.0
    i0v = i0[valid]
    P[valid] = rk4_step_quaternions(w[i0v], w[i0v + 1], t[i0v + 1] - t[i0v])
    return ordered_product(P)
