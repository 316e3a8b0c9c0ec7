"""The passes over many intervals of a sampled body rate, compiled (numba): each interval's
rotation by classic RK4 on quaternions (method.md M5), under one or several affine rate models
``w = M (w_raw - b)`` (M4), its sensitivity to the model, the largest step and the turn of the
raw rate.

The integration is sequential within an interval: a loop over its samples, reading each row of
``w`` (N, 3) and ``t`` (N,) where it lies (interval k runs from sample ``starts[k]`` to
``ends[k]``, ``ends[k] - starts[k]`` steps on the real timestamps; none is the identity).
Single-threaded on purpose (a batch's workers each run one session on one core). The
signatures take arrays of any layout (``[:, :]`` is numba's layout "A"), so a strided or
memory-mapped signal is read where it lies and nothing compiles again for it; each kernel is
compiled once per machine and then loaded from numba's cache (``cache=True``).
"""

from __future__ import annotations

import numpy as np

from imucal.numerics.rk4.jit import jit
from imucal.numerics.rk4.step import calibrated, hamilton, rk4_step, rotation_matrix

_F1, _F2, _F3, _I1 = "float64[:]", "float64[:, :]", "float64[:, :, :]", "int64[:]"
_ROWS = f"{_F2}, {_F1}, {_I1}, {_I1}"  # w, t, starts, ends


@jit()
def _normalised(qw, qx, qy, qz):  # pragma: no cover - compiled
    """``q / |q|``: renormalising after every step equals normalising the product once at the
    end, because ``|q (x) P| = |q| |P|``. Written as ``sqrt(sum q^2)``, not ``abs``, so that it
    is analytic (the complex step)."""
    n = np.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    return qw / n, qx / n, qy / n, qz / n


@jit()
def rotation(w, t, s, e, M, b):  # pragma: no cover - compiled
    """The rotation (normalised) over samples ``s .. e`` under ``w = M (w_raw - b)``: the
    ordered product of the RK4 steps (method.md M5)."""
    qw, qx, qy, qz = 1.0, 0.0, 0.0, 0.0
    c0x, c0y, c0z, _, _, _ = calibrated(w, s, M, b)
    for n in range(s, e):
        c1x, c1y, c1z, _, _, _ = calibrated(w, n + 1, M, b)
        pw, px, py, pz = rk4_step(c0x, c0y, c0z, c1x, c1y, c1z, t[n + 1] - t[n])
        qw, qx, qy, qz = hamilton(qw, qx, qy, qz, pw, px, py, pz)
        c0x, c0y, c0z = c1x, c1y, c1z
    return _normalised(qw, qx, qy, qz)


@jit()
def _put(out, qw, qx, qy, qz):  # pragma: no cover - compiled
    out[0] = qw
    out[1] = qx
    out[2] = qy
    out[3] = qz


@jit(f"void({_ROWS}, {_F3}, {_F2}, {_F3})", nogil=True)
def integrate(w, t, starts, ends, M, b, out):  # pragma: no cover - compiled
    """``out[m, k]`` (k, K, 4): interval k's rotation under model m, ``M[m]`` (3, 3) and
    ``b[m]`` (3,). Each model's arithmetic is the same as alone; an interval's samples are
    read from memory once for all the models (then from the cache)."""
    for k in range(starts.shape[0]):
        for m in range(M.shape[0]):
            qw, qx, qy, qz = rotation(w, t, starts[k], ends[k], M[m], b[m])
            _put(out[m, k], qw, qx, qy, qz)


@jit(f"void({_ROWS}, {_F3}, {_F2}, {_F2})", nogil=True)
def integrate_each(w, t, starts, ends, M, b, out):  # pragma: no cover - compiled
    """``out[k]`` (K, 4): interval k's rotation under a model of its own, ``M[k]``, ``b[k]``."""
    for k in range(starts.shape[0]):
        qw, qx, qy, qz = rotation(w, t, starts[k], ends[k], M[k], b[k])
        _put(out[k], qw, qx, qy, qz)


@jit()
def _accumulate(acc, R, c, dx, dy, dz):  # pragma: no cover - compiled
    """``acc[3 a + i, :] += R[3 a + i] c (dx, dy, dz, 1)``: one sample's trapezoid term."""
    ex, ey, ez = dx * c, dy * c, dz * c
    for r in range(9):
        acc[r, 0] += R[r] * ex
        acc[r, 1] += R[r] * ey
        acc[r, 2] += R[r] * ez
        acc[r, 3] += R[r] * c


@jit(f"void({_ROWS}, {_F2}, {_F1}, {_F2}, {_F3})", nogil=True)
def sensitivity(w, t, starts, ends, M, b, q_out, S_out):  # pragma: no cover - compiled
    """Interval k's rotation ``q_out[k]`` (K, 4), the same to the bit as :func:`integrate`'s,
    and its sensitivity to the model, ``S_out[k]`` (K, 9, 4),

        ``S[k, 3 a + i, j] = integral over the interval of R(t)[a, i] d_j(t) dt``,

    ``R(t)`` the rotation from the interval's start to ``t`` and ``d = (w_raw - b, 1)``.

    Perturbing the rate by ``dw(t)`` turns the end orientation by the body-frame rotation vector
    ``dphi = R(T)^T integral of R(t) dw(t) dt`` (the variational equation of
    ``dR/dt = R [w]x``), and every parameter of M4 perturbs the rate linearly in ``d``: so a
    fit's whole Jacobian comes from ``S`` by small contractions, in one pass instead of one
    integration per parameter. The integral is the trapezoidal rule on the samples (each
    sample weighted by half of each step it bounds; ``R`` at a sample is that of the product
    of the steps before it): its relative error, about ``(w h)^2 / 12`` per step, is a few 1e-5
    at 100 Hz and fast turns, well below what a fit needs of a Jacobian (its residuals are
    always evaluated exactly).
    """
    acc = np.empty((9, 4))  # contiguous: 14 % faster than accumulating in S_out (layout A)
    for k in range(starts.shape[0]):
        s, e = starts[k], ends[k]
        acc[:, :] = 0.0
        qw, qx, qy, qz = 1.0, 0.0, 0.0, 0.0
        c0x, c0y, c0z, d0x, d0y, d0z = calibrated(w, s, M, b)
        h_before = 0.0
        for n in range(s, e + 1):
            h = t[n + 1] - t[n] if n < e else 0.0
            R = rotation_matrix(qw, qx, qy, qz)
            _accumulate(acc, R, 0.5 * h + 0.5 * h_before, d0x, d0y, d0z)
            if n == e:
                break
            c1x, c1y, c1z, d1x, d1y, d1z = calibrated(w, n + 1, M, b)
            pw, px, py, pz = rk4_step(c0x, c0y, c0z, c1x, c1y, c1z, h)
            qw, qx, qy, qz = hamilton(qw, qx, qy, qz, pw, px, py, pz)
            c0x, c0y, c0z, d0x, d0y, d0z = c1x, c1y, c1z, d1x, d1y, d1z
            h_before = h
        S_out[k, :, :] = acc
        _put(q_out[k], *_normalised(qw, qx, qy, qz))


@jit(f"float64({_ROWS}, {_F2}, {_F1})", nogil=True)
def max_step(w, t, starts, ends, M, b):  # pragma: no cover - compiled
    """The largest angle turned in one step, ``|M (w_raw(t_n) - b)| (t_(n+1) - t_n)`` with the
    rate at the step's start (0 without steps)."""
    out = 0.0
    for k in range(starts.shape[0]):
        for n in range(starts[k], ends[k]):
            cx, cy, cz, _, _, _ = calibrated(w, n, M, b)
            out = max(out, np.sqrt(cx * cx + cy * cy + cz * cz) * (t[n + 1] - t[n]))
    return out


@jit(f"void({_ROWS}, {_F1}, {_F1})", nogil=True)
def raw_turn(w, t, starts, ends, b, out):  # pragma: no cover - compiled
    """``out[k]``: the integral of ``|w_raw - b|`` over interval k, the rate of each step the
    mean of its two samples."""
    for k in range(starts.shape[0]):
        total = 0.0
        for n in range(starts[k], ends[k]):
            x = 0.5 * (w[n, 0] + w[n + 1, 0]) - b[0]
            y = 0.5 * (w[n, 1] + w[n + 1, 1]) - b[1]
            z = 0.5 * (w[n, 2] + w[n + 1, 2]) - b[2]
            total += np.sqrt(x * x + y * y + z * z) * (t[n + 1] - t[n])
        out[k] = total
