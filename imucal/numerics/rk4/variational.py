"""The variational equation of the rotation: how every interval's end orientation moves when
the affine rate model ``w = M (w_raw - b)`` (method.md M4) moves, from one prefix scan of the
RK4 steps instead of a finite-difference integration per parameter (method.md M5).

Perturbing the rate by ``dw(t)`` turns the end orientation by the body-frame rotation vector
``dphi = R(T)^T integral of R(t) dw(t) dt`` (the variational equation of ``dR/dt = R [w]x``),
and every parameter of M4 perturbs the rate linearly in ``d = (w_raw - b, 1)``: so the whole
Jacobian comes from ``S = integral of R(t) d(t)^T dt`` by small contractions.
"""

from __future__ import annotations

import numpy as np

from imucal.numerics.rk4.affine import calibrator
from imucal.numerics.rk4.buckets import Bucket
from imucal.numerics.rk4.hamilton import Quat, Vec, mul
from imucal.numerics.rk4.integrate import SLAB
from imucal.numerics.rk4.prefix_scan import prefix_rows
from imucal.numerics.rk4.rotation_matrix import matrix_rows
from imucal.numerics.rk4.step import rk4_raw


def sensitivity(buckets: list[Bucket], n: int, samples: list[Vec], M: np.ndarray, b: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """Every interval's rotation ``q`` (n, 4), normalised, and ``S`` (n, 3, 3, 4),
    ``S[k, :, i, j] = integral of R(t)[:, i] d_j(t) dt`` over interval k, with ``R(t)`` the
    rotation from the interval's start to ``t`` and ``d = (w_raw - b, 1)``, for the model
    ``w = M (w_raw - b)`` (M4); ``samples`` are the raw rates of each bucket.

    One prefix scan of the steps (about two evaluations of the cost) replaces the 9 cost
    evaluations of a finite-difference Jacobian. The integral is the trapezoidal rule on the
    samples: its relative error, about ``(w h)^2 / 12`` per step, is a few 1e-5 at 100 Hz and
    fast turns, well below what a fit needs of a Jacobian (its residuals are always evaluated
    exactly).
    """
    cal = calibrator([(M, b)])
    b = np.asarray(b, float).tolist()
    q_out = np.empty((n, 4))
    q_out[:] = (1.0, 0.0, 0.0, 0.0)
    S_out = np.zeros((n, 9, 4))
    for (idx, _, _, dt, dt2), w in zip(buckets, samples):
        carry, S = _bucket_sensitivity(w, b, cal, dt, dt2)
        if carry is not None:
            q_out[idx] = np.stack(carry, axis=-1)
        S_out[idx] = S
    q_out /= np.linalg.norm(q_out, axis=-1, keepdims=True)
    return q_out, S_out.reshape(n, 3, 3, 4)


def trapezoid_weights(w: Vec, b: list[float], dt: np.ndarray, r0: int = 0,
                      r1: int | None = None) -> np.ndarray:
    """``d = (w_raw - b, 1)`` at every sample times its trapezoid weight (0 in the padding),
    transition-major (K_b, rows, 4) so that each slab's sum over samples is one contiguous
    matrix product per interval; samples ``r0 .. r1 - 1`` of the L + 1 (all by default), each
    value the same as in the whole."""
    L, kb = dt.shape
    r1 = L + 1 if r1 is None else r1
    c = np.zeros((r1 - r0, kb))
    c[:max(min(r1, L) - r0, 0)] += 0.5 * dt[r0:r1]  # the step starting at the sample
    lo = max(r0, 1)
    c[lo - r0:] += 0.5 * dt[lo - 1:r1 - 1]  # the step ending at it
    weights = np.empty((kb, r1 - r0, 4))
    weights[:, :, 3] = c.T
    for j in range(3):
        weights[:, :, j] = ((w[j][r0:r1] - b[j]) * c).T
    return weights


def _bucket_sensitivity(w: Vec, b: list[float], cal, dt: np.ndarray, dt2: np.ndarray
                        ) -> tuple[Quat | None, np.ndarray]:
    """The end rotation (None without steps) and ``S`` (K_b, 9, 4) of one bucket from its raw
    rates ``w`` ((L + 1, K_b) per component), a slab of rows at a time: each slab's
    orientations are a prefix scan relative to the slab's start, and the rotation carried in
    from the slabs before is applied to the slab's sum once. The calibrated rates and the
    weights are made a slab at a time too (no temporaries the size of the bucket)."""
    L, kb = dt.shape
    # The first sample: R = I, so S[k, 3 i + i, j] gets its weighted d_j.
    S = np.zeros((kb, 9, 4))
    first = trapezoid_weights(w, b, dt, 0, 1)
    for i in range(3):
        S[:, 4 * i, :] = first[:, 0, :]
    carry = None
    rows = max(1, SLAB // max(kb, 1))
    R = np.empty((kb, 9, min(rows, L)))
    for r0 in range(0, L, rows):
        r1 = min(r0 + rows, L)
        om = tuple(x[:, 0, :] for x in cal(tuple(x[r0:r1 + 1][:, None, :] for x in w)))
        P = rk4_raw(tuple(x[:-1] for x in om), tuple(x[1:] for x in om), dt[r0:r1], dt2[r0:r1])
        Q = prefix_rows(P)  # orientation at samples r0 + 1 .. r1 relative to r0
        Rs = R[:, :, :r1 - r0]
        matrix_rows(Q, Rs.transpose(2, 1, 0))
        part = np.matmul(Rs, trapezoid_weights(w, b, dt, r0 + 1, r1 + 1))  # (kb, 9, 4)
        if carry is None:
            carry = tuple(x[-1] for x in Q)
        else:
            part = _rotated(carry, part)
            carry = mul(carry, tuple(x[-1] for x in Q))
        S += part
    return carry, S


def _rotated(carry: Quat, part: np.ndarray) -> np.ndarray:
    """``R(carry) part`` for every interval's (9, 4) sum ((K_b, 9, 4)): ``R(carry (x) Q_n) =
    R(carry) R(Q_n)``, so the slab's sum is rotated once instead of every sample's
    orientation."""
    kb = part.shape[0]
    Rc = matrix_rows(tuple(x[None] for x in carry), np.empty((1, 9, kb)))
    Rc = Rc[0].T.reshape(kb, 3, 3)
    return np.matmul(Rc, part.reshape(kb, 3, 12)).reshape(kb, 9, 4)
