"""The variational equation of the rotation: how every interval's end orientation moves when
the affine rate model ``w = M (w_raw - b)`` (method.md M4) moves, from one prefix scan of the
RK4 steps instead of a finite-difference integration per parameter (method.md M5).

Perturbing the rate by ``dw(t)`` turns the end orientation by the body-frame rotation vector
``dphi = R(T)^T integral of R(t) dw(t) dt`` (the variational equation of ``dR/dt = R [w]x``),
and every parameter of M4 perturbs the rate linearly in ``d = (w_raw - b, 1)``: so the whole
Jacobian comes from ``S = integral of R(t) d(t)^T dt`` by small contractions.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from imucal.numerics.rk4.affine import calibrator
from imucal.numerics.rk4.buckets import Bucket
from imucal.numerics.rk4.hamilton import Quat, Vec, mul
from imucal.numerics.rk4.integrate import slab_steps
from imucal.numerics.rk4.lazy import Slab, slab_ranges, slab_rows
from imucal.numerics.rk4.prefix_scan import prefix_and_product
from imucal.numerics.rk4.rotation_matrix import matrix_rows


class Sensitivity(NamedTuple):
    """One pass over the steps under a model: ``q`` (n, 4) every interval's rotation, the same
    to the bit as :func:`~.integrate.integrate_buckets` gives; ``S`` (n, 3, 3, 4) its
    sensitivity; ``q_scan`` (n, 4) the rotation as the prefix scan behind ``S`` composes it
    (the same to rounding)."""

    q: np.ndarray
    S: np.ndarray
    q_scan: np.ndarray


def sensitivity(buckets: list[Bucket], n: int, samples: list, M: np.ndarray, b: np.ndarray
                ) -> Sensitivity:
    """Every interval's rotation and ``S``, ``S[k, :, i, j] = integral of R(t)[:, i] d_j(t)
    dt`` over interval k, with ``R(t)`` the rotation from the interval's start to ``t`` and
    ``d = (w_raw - b, 1)``, for the model ``w = M (w_raw - b)`` (M4); ``samples`` are the raw
    rates of each bucket.

    One prefix scan of the steps (about two evaluations of the cost) replaces the 9 cost
    evaluations of a finite-difference Jacobian. The integral is the trapezoidal rule on the
    samples: its relative error, about ``(w h)^2 / 12`` per step, is a few 1e-5 at 100 Hz and
    fast turns, well below what a fit needs of a Jacobian (its residuals are always evaluated
    exactly).
    """
    cal = calibrator([(M, b)])
    b = np.asarray(b, float).tolist()
    q_out = np.empty((2, n, 4))
    q_out[:] = (1.0, 0.0, 0.0, 0.0)
    S_out = np.zeros((n, 9, 4))
    for bucket, w in zip(buckets, samples):
        q, scan, S = _bucket_sensitivity(slab_rows(bucket, w), bucket.dt.shape, b, cal)
        q_out[0, bucket.idx] = np.stack(np.broadcast_arrays(*q), axis=-1)
        q_out[1, bucket.idx] = np.stack(scan, axis=-1)
        S_out[bucket.idx] = S
    q_out /= np.linalg.norm(q_out, axis=-1, keepdims=True)
    return Sensitivity(q_out[0], S_out.reshape(n, 3, 3, 4), q_out[1])


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
    return _weighted(tuple(x[r0:r1] for x in w), b, c)


def _weighted(w: Vec, b: list[float], c: np.ndarray) -> np.ndarray:
    """``(w - b, 1)`` times the weights ``c`` (rows, K_b), transition-major (K_b, rows, 4)."""
    weights = np.empty((c.shape[1], c.shape[0], 4))
    weights[:, :, 3] = c.T
    for j in range(3):
        weights[:, :, j] = ((w[j] - b[j]) * c).T
    return weights


def _slab_weights(s: Slab, b: list[float]) -> np.ndarray:
    """:func:`trapezoid_weights` of a slab's samples after its first (``r0 + 1 .. r1``): half
    the step starting at each (the next slab's first for the last) and half the one ending
    at it, added in that order (the same values)."""
    c = np.zeros(s.dt.shape)
    c[:-1] += 0.5 * s.dt[1:]
    c[-1] += 0.5 * s.dt_next
    c += 0.5 * s.dt
    return _weighted(tuple(x[1:] for x in s.w), b, c)


def _bucket_sensitivity(src, shape: tuple[int, int], b: list[float], cal
                        ) -> tuple[Quat, Quat, np.ndarray]:
    """The end rotation, by ordered products (:func:`.integrate.integrate_buckets`'s) and by
    the prefix scan, and ``S`` (K_b, 9, 4) of one bucket of ``shape`` (L, K_b) whose slabs
    ``src`` reads, a slab of rows at a time: each slab's orientations are a prefix scan
    relative to the slab's start, and the rotation carried in from the slabs before is applied
    to the slab's sum once (no temporaries the size of the bucket)."""
    L, kb = shape
    S = np.zeros((kb, 9, 4))
    acc = carry = None
    for r0, r1 in slab_ranges(L, kb):
        s = src.slab(r0, r1, ahead=True)
        if r0 == 0:  # the first sample: R = I, so S[k, 3 i + i, j] gets its weighted d_j
            first = _weighted(tuple(x[:1] for x in s.w), b, np.zeros((1, kb)) + 0.5 * s.dt[:1])
            for i in range(3):
                S[:, 4 * i, :] = first[:, 0, :]
        # orientations at r0 + 1 .. r1 from r0, and the slab's product as integrated alone
        Q, q = prefix_and_product(tuple(x[:, 0, :] for x in slab_steps(s.w, s.dt, s.dt2, cal)))
        acc = q if acc is None else mul(acc, q)
        part = _slab_sum(Q, _slab_weights(s, b))
        end = tuple(x[-1].copy() for x in Q)  # the slab's rotation; the rest of Q is let go
        del Q
        if carry is None:
            carry = end
        else:
            part = _rotated(carry, part)
            carry = mul(carry, end)
        S += part
        del s  # views of the block read: let it go when the next is read
    return acc, carry, S


# Column chunks of a slab whose rotation matrices are made at once (in two layouts): a quarter
# slab each, so that they take 1.2 MB, not 4.7 MB (at 6 h).
R_CHUNKS = 4


def _slab_sum(Q: Quat, W: np.ndarray) -> np.ndarray:
    """``sum over the slab's samples of R(Q) W`` per interval, (K_b, 9, 4), one matrix product
    per interval. The matrices are written time-major (contiguous), then laid out
    interval-major by one copy (scattered writes into that layout cost twice as much at 6 h),
    a few columns at a time."""
    m, kb = Q[0].shape
    part = np.empty((kb, 9, 4))
    step = -(-kb // R_CHUNKS)
    for c0 in range(0, kb, step):
        c1 = min(c0 + step, kb)
        R = matrix_rows(tuple(x[:, c0:c1] for x in Q), np.empty((m, 9, c1 - c0)))
        np.matmul(np.ascontiguousarray(R.transpose(2, 1, 0)), W[c0:c1], out=part[c0:c1])
    return part


def _rotated(carry: Quat, part: np.ndarray) -> np.ndarray:
    """``R(carry) part`` for every interval's (9, 4) sum ((K_b, 9, 4)): ``R(carry (x) Q_n) =
    R(carry) R(Q_n)``, so the slab's sum is rotated once instead of every sample's
    orientation."""
    kb = part.shape[0]
    Rc = matrix_rows(tuple(x[None] for x in carry), np.empty((1, 9, kb)))
    Rc = Rc[0].T.reshape(kb, 3, 3)
    return np.matmul(Rc, part.reshape(kb, 3, 12)).reshape(kb, 9, 4)
