"""Orientation from the gyroscope: classic RK4 on quaternions (method.md M5), vectorised.

For ``dq/dt = 1/2 q (x) W(t)`` (W the pure quaternion of the body rate) one RK4 step is linear
in ``q``: ``q_(n+1) = q_n (x) P_n``, with ``P_n`` a quaternion built from the rates at the step's
start, middle and end only. Renormalising after every step equals normalising the product once
at the end, because ``|q (x) P| = |q| |P|``. So a whole transition is the ordered product
``P_0 (x) P_1 (x) ... (x) P_(L-1)``, normalised: every ``P_n`` of every transition is built in
one vector operation, and the products are reduced pairwise, in ``log2(L)`` vector operations,
for all transitions at once (no per-sample Python loop; linear work in the number of samples).

With the thesis's half-step rate (the mean of the two samples) the four RK4 stages collapse to
a closed form (:func:`rk4_steps`), about a third of the arithmetic of the stages written out.

Quaternions are handled here as four separate component arrays (w, x, y, z). The steps of many
transitions are laid out time-major, ``(L, K)`` (step, transition), so that every operation of
the reduction reads contiguous runs of K values; transitions of very different lengths go to
different buckets (:class:`StepLayout`) so that padding stays small, and long buckets are
processed a slab of rows at a time so that the temporaries stay in cache.
"""

from __future__ import annotations

import numpy as np

Vec = tuple[np.ndarray, np.ndarray, np.ndarray]
Quat = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]

# Elements (rows x transitions) evaluated at once: large enough that numpy's per-call overhead
# is small, small enough that the ~20 live temporaries stay in cache (measured in bench/).
SLAB = 32768
# A bucket of its own costs a few hundred numpy calls per evaluation (about the work of this
# many padded steps); shorter transitions share the longer bucket unless that saves more.
BUCKET_OVERHEAD_STEPS = 10000
BUCKET_RATIO = 0.8


def mul(p: Quat, q: Quat) -> Quat:
    """Hamilton product ``p (x) q`` of component arrays (fresh outputs, in-place accumulation)."""
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    w = pw * qw
    w -= px * qx
    w -= py * qy
    w -= pz * qz
    x = pw * qx
    x += px * qw
    x += py * qz
    x -= pz * qy
    y = pw * qy
    y -= px * qz
    y += py * qw
    y += pz * qx
    z = pw * qz
    z += px * qy
    z -= py * qx
    z += pz * qw
    return w, x, y, z


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


# p (x) q = H @ vec(p q'): the Hamilton product as a fixed linear map of the 16 products p_i q_j.
_HAMILTON = np.zeros((4, 16))
for _i, _j, _k, _s in [(0, 0, 0, 1), (0, 1, 1, -1), (0, 2, 2, -1), (0, 3, 3, -1),
                       (1, 0, 1, 1), (1, 1, 0, 1), (1, 2, 3, 1), (1, 3, 2, -1),
                       (2, 0, 2, 1), (2, 1, 3, -1), (2, 2, 0, 1), (2, 3, 1, 1),
                       (3, 0, 3, 1), (3, 1, 2, 1), (3, 2, 1, -1), (3, 3, 0, 1)]:
    _HAMILTON[_i, 4 * _j + _k] = _s
# Below this many elements per component, products go through one matrix product on stacked
# arrays (3 numpy calls instead of 28): small arrays are bound by per-call overhead. Kept
# under OpenBLAS's threading threshold for this (4 x 16) @ (16 x N) product, so that it never
# wakes a helper thread (which would then spin on the second core).
SMALL = 2048


def _mul_stacked(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product of stacked (4, ...) arrays."""
    prod = p[:, None] * q[None, :]
    return (_HAMILTON @ prod.reshape(16, -1)).reshape(p.shape)


def product_rows(P: Quat) -> Quat:
    """``P[0] (x) P[1] (x) ...`` along axis 0 of (L, ...) component arrays, pairwise.

    Each level multiplies rows ``2i`` and ``2i+1`` (strided views whose rows are contiguous);
    an odd last row is folded into the last product. Once the arrays are small the four
    components are stacked and each product is one matrix product. Not normalised.
    """
    while P[0].shape[0] > 1 and P[0].size > SMALL:
        n = P[0].shape[0]
        m = n - (n % 2)
        R = mul(tuple(c[0:m:2] for c in P), tuple(c[1:m:2] for c in P))
        if n % 2:
            k = m // 2
            last = mul(tuple(c[k - 1:k] for c in R), tuple(c[n - 1:n] for c in P))
            for c, v in zip(R, last):
                c[k - 1:k] = v
        P = R
    if P[0].shape[0] == 1:
        return tuple(c[0] for c in P)
    S = np.stack(P)  # (4, n, ...)
    while S.shape[1] > 1:
        n = S.shape[1]
        m = n - (n % 2)
        R = _mul_stacked(S[:, 0:m:2], S[:, 1:m:2])
        if n % 2:
            k = m // 2
            R[:, k - 1:k] = _mul_stacked(R[:, k - 1:k], S[:, n - 1:n])
        S = R
    return tuple(S[:, 0])


def prefix_rows(P: Quat) -> Quat:
    """Inclusive prefix products ``P[0] (x) ... (x) P[n]`` along axis 0 of (L, ...) component
    arrays, for every ``n``, in ``2 L`` products and ``log2(L)`` levels.

    The rows are multiplied in pairs, the pairs' prefixes found recursively, and each even row
    then gets the prefix of the pairs before it (the work-efficient parallel scan).
    """
    n = P[0].shape[0]
    if n == 1:
        return tuple(c.copy() for c in P)
    m = n // 2
    pairs = prefix_rows(mul(tuple(c[0:2 * m:2] for c in P), tuple(c[1:2 * m:2] for c in P)))
    out = tuple(np.empty_like(c) for c in P)
    for o, c, s in zip(out, P, pairs):
        o[1:2 * m:2] = s  # row 2j + 1: the prefix of pairs 0..j
        o[0] = c[0]
    if n > 2:
        even = mul(tuple(s[0:(n - 1) // 2] for s in pairs), tuple(c[2:n:2] for c in P))
        for o, e in zip(out, even):
            o[2:n:2] = e  # row 2j: the prefix of pairs 0..j-1, times row 2j
    return out


def ordered_product_soa(P: Quat) -> Quat:
    """``P[..., 0] (x) P[..., 1] (x) ...`` along the last axis, as a normalised (..., 4) array.

    Products of unit quaternions stay unit to rounding, so only the result is renormalised.
    """
    P = tuple(np.moveaxis(np.asarray(x, float), -1, 0) for x in P)
    out = np.stack(product_rows(P), axis=-1)
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


def _buckets(n_steps: np.ndarray) -> list[np.ndarray]:
    """Transitions grouped by length (indices into ``n_steps``), longest first.

    Lengths fall into classes a factor ``BUCKET_RATIO`` apart; a class shares the bucket of
    the longer ones before it unless a bucket of its own saves more padded steps than it costs.
    """
    if len(n_steps) == 0:
        return []
    order = np.argsort(-n_steps, kind="stable")
    lengths = np.maximum(n_steps[order], 1)
    top = lengths[0]
    cls = np.floor(np.log(top / lengths) / -np.log(BUCKET_RATIO)).astype(np.int64)
    edges = np.flatnonzero(np.diff(cls)) + 1
    groups = np.split(np.arange(len(order)), edges)
    out: list[list[int]] = []
    cur_len = None
    for g in groups:
        g_len = int(lengths[g[0]])
        if cur_len is not None and len(g) * (cur_len - g_len) < BUCKET_OVERHEAD_STEPS:
            out[-1].extend(g.tolist())
            continue
        out.append(g.tolist())
        cur_len = g_len
    return [np.sort(order[np.array(b)]) for b in out]


class StepLayout:
    """The RK4 steps of many transitions, laid out once for repeated integration.

    Transition k takes ``ends[k] - starts[k]`` steps from sample ``starts[k]`` on the
    timestamps ``t``. Each bucket holds the transitions ``index`` as time-major arrays: the
    sample index of every step's start (``i0``, (L + 1, K_b): the last row is the end of the
    last step), which of those samples belong to the transition (``valid``), and every step's
    ``dt`` (L, K_b; 0 for padding) and ``dt^2``.
    """

    def __init__(self, t: np.ndarray, starts: np.ndarray, ends: np.ndarray):
        t = np.asarray(t, float)
        self.starts = np.asarray(starts, np.int64)
        self.ends = np.asarray(ends, np.int64)
        self.n = len(self.starts)
        n_steps = self.ends - self.starts
        self.buckets = []
        for idx in _buckets(n_steps):
            L = int(max(n_steps[idx].max(), 1))
            j = np.arange(L + 1)[:, None]
            valid = j <= n_steps[idx][None, :]  # samples: L steps have L + 1 ends
            i0 = np.where(valid, np.minimum(self.starts[idx][None, :] + j, len(t) - 1), 0)
            step = valid[1:]  # step j runs from sample j to sample j + 1
            dt = np.where(step, t[i0[1:]] - t[i0[:-1]], 0.0)
            self.buckets.append((idx, i0, valid, dt, dt * dt))

    def gather(self, comps: list[np.ndarray]) -> list[Vec]:
        """The samples of every transition, per bucket ((L + 1, K_b) per component, zero in the
        padding): step j runs from row j to row j + 1, so each sample is calibrated once."""
        return [tuple(np.where(valid, c[i0], 0.0) for c in comps)
                for _, i0, valid, _, _ in self.buckets]

    def integrate(self, samples: list[Vec], models: list[tuple] | None = None) -> np.ndarray:
        """Quaternions (k, K, 4), normalised, of every transition under each of k models.

        ``samples`` are :meth:`gather`'s arrays (raw rates); ``models`` a list of ``(M, b)``,
        the calibrated rate being ``M (w - b)`` (M4), or ``None`` for the rates as they are
        (k = 1). Slab by slab of rows, each model's arithmetic is the same as alone.
        """
        k = 1 if models is None else len(models)
        out = np.empty((k, self.n, 4))
        out[:] = (1.0, 0.0, 0.0, 0.0)
        cal = None if models is None else calibrator(models)
        for (idx, _, _, dt, dt2), w in zip(self.buckets, samples):
            L, kb = dt.shape
            # Slabs depend on the layout only, not on k: the reduction tree, and so the
            # rounding, is the same for a model alone and among several.
            rows = max(1, SLAB // max(kb, 1))
            acc = None
            for r0 in range(0, L, rows):
                r1 = min(r0 + rows, L)
                c = tuple(x[r0:r1 + 1, None, :] for x in w)
                if cal is not None:
                    c = cal(c)
                a = tuple(x[:-1] for x in c)
                b = tuple(x[1:] for x in c)
                q = product_rows(rk4_raw(a, b, dt[r0:r1, None, :], dt2[r0:r1, None, :]))
                acc = q if acc is None else mul(acc, q)
            out[:, idx] = np.stack(np.broadcast_arrays(*acc), axis=-1)
        return out / np.linalg.norm(out, axis=-1, keepdims=True)


    def sensitivity(self, samples: list[Vec], M: np.ndarray, b: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
        """What the gyroscope fit's Jacobian needs, for the model ``w = M (w_raw - b)`` (M4).

        Returns every transition's rotation ``q`` (n, 4), normalised, and ``S`` (n, 3, 3, 4),
        ``S[k, :, i, j] = integral of R(t)[:, i] d_j(t) dt`` over transition k, with ``R(t)``
        the rotation from the transition's start to ``t`` and ``d = (w_raw - b, 1)``.

        Why: perturbing the rate by ``dw(t)`` turns the end orientation by the body-frame
        rotation vector ``dphi = R(T)^T integral of R(t) dw(t) dt`` (the variational equation of
        ``dR/dt = R [w]x``), and every parameter of M4 perturbs the rate linearly in ``d``, so
        the 9 (or 12) columns of the Jacobian come from ``S`` by small contractions. One
        prefix scan of the steps (about two evaluations of the cost) replaces the 9 cost
        evaluations of a finite-difference Jacobian. The integral is the trapezoidal rule on
        the samples: its relative error, about ``(w h)^2 / 12`` per step, is a few 1e-5 at
        100 Hz and fast turns, well below what the fit needs of a Jacobian (the residuals
        themselves are always evaluated exactly).
        """
        cal = calibrator([(M, b)])
        b = np.asarray(b, float).tolist()
        q_out = np.empty((self.n, 4))
        q_out[:] = (1.0, 0.0, 0.0, 0.0)
        S_out = np.zeros((self.n, 9, 4))
        for (idx, _, _, dt, dt2), w in zip(self.buckets, samples):
            L, kb = dt.shape
            c = np.zeros((L + 1, kb))  # trapezoid weight of each sample (0 in the padding)
            c[:-1] += 0.5 * dt
            c[1:] += 0.5 * dt
            # Transition-major (kb, L + 1, 4), so that each slab's sum over samples is one
            # contiguous matrix product per transition.
            weights = np.empty((kb, L + 1, 4))
            weights[:, :, 3] = c.T
            for j in range(3):
                weights[:, :, j] = ((w[j] - b[j]) * c).T
            om = tuple(x[:, 0, :] for x in cal(tuple(x[:, None, :] for x in w)))
            # The first sample: R = I, so S[k, 3 i + i, j] gets its weighted d_j.
            S = np.zeros((kb, 9, 4))
            for i in range(3):
                S[:, 4 * i, :] = weights[:, 0, :]
            carry = None
            rows = max(1, SLAB // max(kb, 1))
            R = np.empty((kb, 9, min(rows, L)))
            for r0 in range(0, L, rows):
                r1 = min(r0 + rows, L)
                P = rk4_raw(tuple(x[r0:r1] for x in om), tuple(x[r0 + 1:r1 + 1] for x in om),
                            dt[r0:r1], dt2[r0:r1])
                Q = prefix_rows(P)  # orientation at samples r0 + 1 .. r1 relative to r0
                Rs = R[:, :, :r1 - r0]
                _matrix_rows(Q, Rs.transpose(2, 1, 0))
                part = np.matmul(Rs, weights[:, r0 + 1:r1 + 1])  # (kb, 9, 4)
                if carry is None:
                    carry = tuple(x[-1] for x in Q)
                else:
                    # R(carry (x) Q_n) = R(carry) R(Q_n): rotate the slab's sum once instead
                    # of every sample's orientation.
                    Rc = _matrix_rows(tuple(x[None] for x in carry), np.empty((1, 9, kb)))
                    Rc = Rc[0].T.reshape(kb, 3, 3)
                    part = np.matmul(Rc, part.reshape(kb, 3, 12)).reshape(kb, 9, 4)
                    carry = mul(carry, tuple(x[-1] for x in Q))
                S += part
            if carry is not None:
                q_out[idx] = np.stack(carry, axis=-1)
            S_out[idx] = S
        q_out /= np.linalg.norm(q_out, axis=-1, keepdims=True)
        return q_out, S_out.reshape(self.n, 3, 3, 4)


def _matrix_rows(q: Quat, out: np.ndarray) -> np.ndarray:
    """Rotation matrices, row-major entries along axis 1 of ``out`` (rows, 9, K), of (rows, K)
    component arrays; exact for quaternions that are not quite unit (RK4 steps are not).

    Written into ``out`` with two scratch arrays: fresh temporaries of this size cost more in
    page faults than in arithmetic here (measured: 5.5 ms against 0.6 ms per slab)."""
    w, x, y, z = q
    s = w * w
    a = np.multiply(x, x)
    s += a
    np.multiply(y, y, out=a)
    s += a
    np.multiply(z, z, out=a)
    s += a
    np.divide(2.0, s, out=s)
    xs, ys, zs = x * s, y * s, z * s
    b = s  # s is no longer needed
    e = [out[:, i] for i in range(9)]
    # Off the diagonal: entries (1, 3) = xy -/+ wz, (6, 2) = xz -/+ wy, (5, 7) = yz -/+ wx.
    for u, us, ws, minus, plus in ((x, ys, zs, 1, 3), (x, zs, ys, 6, 2), (y, zs, xs, 5, 7)):
        np.multiply(u, us, out=a)
        np.multiply(w, ws, out=b)
        np.subtract(a, b, out=e[minus])
        np.add(a, b, out=e[plus])
    np.multiply(x, xs, out=xs)  # xx
    np.multiply(y, ys, out=ys)  # yy
    np.multiply(z, zs, out=zs)  # zz
    for k, (p, r) in ((0, (ys, zs)), (4, (xs, zs)), (8, (xs, ys))):
        np.add(p, r, out=e[k])
        np.subtract(1.0, e[k], out=e[k])
    return out


def calibrator(models: list[tuple]):
    """M4 on component arrays for k models at once: ``w_i = sum_j M_ij (w_raw_j - b_j)``.

    Raw slabs are (rows, 1, K); the result (rows, k, K). Per element the arithmetic is the
    same as for one model, in the same order."""
    M = np.array([np.asarray(m, float) for m, _ in models])  # (k, 3, 3)
    b = np.array([np.asarray(bb, float) for _, bb in models])  # (k, 3)
    same_bias = bool(np.all(b == b[:1]))
    coef = [[M[:, i, j][None, :, None] for j in range(3)] for i in range(3)]
    if same_bias:
        b0 = b[0].tolist()
    else:
        bias = [b[:, j][None, :, None] for j in range(3)]

    def apply(w: Vec) -> Vec:
        if same_bias:
            d = [w[j] - b0[j] for j in range(3)]
        else:
            d = [w[j] - bias[j] for j in range(3)]
        out = []
        for i in range(3):
            o = d[0] * coef[i][0]
            o += d[1] * coef[i][1]
            o += d[2] * coef[i][2]
            out.append(o)
        return tuple(out)

    return apply


def integrate_transitions(w: np.ndarray, t: np.ndarray, starts: np.ndarray, ends: np.ndarray
                          ) -> np.ndarray:
    """Body rotation over each interval ``[t[starts[k]], t[ends[k]]]`` from q = identity.

    ``w`` (M, 3) calibrated rates in rad/s at times ``t`` (M,); transition k takes
    ``ends[k] - starts[k]`` RK4 steps on the real timestamps. Returns (K, 4) quaternions.
    """
    if len(starts) == 0:
        return np.zeros((0, 4))
    layout = StepLayout(t, starts, ends)
    comps = [np.ascontiguousarray(w[:, i], dtype=float) for i in range(3)]
    return layout.integrate(layout.gather(comps))[0]
