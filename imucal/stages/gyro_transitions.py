"""The motions between still poses, integrated (method.md §4, M5): each transition's gyroscope
samples laid out once (where to find them; each slab is gathered when read), so every evaluation
of the gyroscope cost integrates all of them at once (RK4 on quaternions, vectorised across
transitions), and its sensitivity to the parameters.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from imucal.models import SensorModel, gyro_T
from imucal.numerics.quaternion import rotate_inverse, to_matrix
from imucal.numerics.rk4 import StepLayout, calibrator, mul, product_rows
from imucal.numerics.rk4.integrate import integrate_buckets
from imucal.numerics.rk4.lazy import Slab, slab_ranges
from imucal.numerics.rk4.variational import Sensitivity


def sorted_position(t, v: np.ndarray, side: str = "left") -> np.ndarray:
    """``np.searchsorted(t, v, side)`` for strictly increasing timestamps ``t`` read only by
    gathers (``t`` may be an array kept on disk): a bisection of all ``v`` at once, ``log2(N)``
    gathers of ``len(v)`` values, the same positions."""
    v = np.asarray(v, float)
    lo = np.zeros(v.shape, np.int64)
    hi = np.full(v.shape, len(t), np.int64)
    while np.any(lo < hi):
        active = lo < hi
        mid = (lo + hi) // 2
        tm = np.asarray(t[np.minimum(mid, len(t) - 1)])
        right = (tm < v) if side == "left" else (tm <= v)
        lo = np.where(active & right, mid + 1, lo)
        hi = np.where(active & ~right, mid, hi)
    return lo


def transition_samples(t, block_times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gyroscope sample indices bracketing each transition: from just before the end of block k
    to just after the start of block k+1."""
    s = np.clip(sorted_position(t, block_times[:-1, 1], side="left") - 1, 0, len(t) - 1)
    e = np.clip(sorted_position(t, block_times[1:, 0], side="right"), 0, len(t) - 1)
    return s, np.maximum(e, s)


# Rotations kept per Transitions, by model ((K, 4) each; with the latest sensitivity, (K, 9, 4)
# more): a fit asks for the Jacobian where it has just evaluated the residuals, and the stage
# integrates the solutions again for its figures.
KEPT_ROTATIONS = 4


class Transitions:
    """The gyroscope samples of every motion between consecutive static blocks, laid out once.

    Transition k runs from the end of block k to the start of block k+1. Its RK4 steps are laid
    out time-major with the other transitions of similar length (:class:`StepLayout`; identity
    steps pad the shorter ones), so every cost evaluation is a handful of vector operations over
    all transitions (M5), and the model is applied to the raw rates slab by slab, each slab
    gathered from the session's arrays when it is read (only a slab of the turns is held).

    ``w_raw`` (N, 3) and ``t`` (N,) are read only by ``len``, ``.shape`` and gathers of rows
    with a 1-D integer array (they may be arrays kept on disk).
    """

    def __init__(self, w_raw, t, block_times: np.ndarray, keep: np.ndarray | None = None):
        s, e = transition_samples(t, block_times)
        if keep is not None:  # only these transitions (a boolean mask over all of them)
            s, e = s[keep], e[keep]
        self.starts, self.ends = s, e
        self.n_steps = e - s
        # Nothing the size of the turns is kept: each slab of samples and step times is
        # gathered from the session's arrays when an integration or the Jacobian reads it
        # (numerics/rk4/lazy.py; the same values to the bit as gathered once).
        self.layout = StepLayout(t, s, e, lazy=True)
        self.rates = self.layout.lazy_samples(w_raw)
        self._rotations: dict[bytes, np.ndarray] = {}  # the latest, by model
        self._latest: tuple[bytes, Sensitivity] | None = None  # the latest sensitivity

    def __len__(self) -> int:
        return len(self.starts)

    @staticmethod
    def _key(M: np.ndarray, b: np.ndarray) -> bytes:
        return np.asarray(M, float).tobytes() + np.asarray(b, float).tobytes()

    def _keep(self, key: bytes, q: np.ndarray) -> np.ndarray:
        self._rotations.pop(key, None)
        self._rotations[key] = q
        while len(self._rotations) > KEPT_ROTATIONS:
            del self._rotations[next(iter(self._rotations))]
        return q

    def rotations(self, model: SensorModel, sensitivity: bool = False) -> np.ndarray:
        """Quaternion of the body rotation over each transition under ``model`` (K, 4).

        With ``sensitivity``, the same pass over the samples also makes what :meth:`jacobian`
        needs at this model (a fit's residuals are followed by its Jacobian at the same point:
        the samples are then read once for both). A model integrated lately is not integrated
        again (the same numbers)."""
        if sensitivity:
            return self._sensitivity(model).q.copy()
        key = self._key(model.matrix, model.b)
        q = self._rotations.get(key)
        if q is None:
            q = self.rotations_many([model])[0]
        return self._keep(key, q).copy()

    def _sensitivity(self, model: SensorModel) -> Sensitivity:
        key = self._key(model.matrix, model.b)
        if self._latest is None or self._latest[0] != key:
            self._latest = None  # let the last one go first
            found = self.layout.sensitivity(self.rates, model.matrix, model.b)
            self._latest = (key, found)
        self._keep(key, self._latest[1].q)
        return self._latest[1]

    def rotations_many(self, models: list[SensorModel]) -> np.ndarray:
        """:meth:`rotations` for several models in one pass (k, K, 4)."""
        return self.layout.integrate(self.rates, [(m.matrix, m.b) for m in models])

    def predict(self, model: SensorModel, u_prev: np.ndarray, sensitivity: bool = False
                ) -> np.ndarray:
        """M5: gravity of block k-1 carried into the body frame of block k, ``R_k^T u_(k-1)``
        (``sensitivity``: see :meth:`rotations`)."""
        return rotate_inverse(self.rotations(model, sensitivity), u_prev)

    def rotations_each(self, M: np.ndarray, b: np.ndarray) -> np.ndarray:
        """:meth:`rotations` with a model of its own for each transition, ``w = M[k] (w_raw -
        b[k])`` over transition k ((K, 3, 3) and (K, 3)); (K, 4). One evaluation's work: the
        cross-validation predicts each held-out turn with its own fold's fit this way."""
        out = np.empty((len(self), 4))
        for bucket, w in zip(self.layout.buckets, self.rates):
            # one column of the bucket per transition: M[k][i, j] as Mk[i, j][k], contiguous
            Mk = np.ascontiguousarray(M[bucket.idx].transpose(1, 2, 0))
            bk = np.ascontiguousarray(b[bucket.idx].T)

            def cal(x, Mk=Mk, bk=bk):  # a slab of rows at a time, not the bucket at once
                d = [v[:, 0] - bk[j] for j, v in enumerate(x)]
                return tuple((d[0] * Mk[i, 0] + d[1] * Mk[i, 1] + d[2] * Mk[i, 2]
                              )[:, None] for i in range(3))

            q = integrate_buckets([bucket], len(self), [w], cal)[0]  # padding: dt = 0
            out[bucket.idx] = q[bucket.idx]
        return out

    def jacobian(self, model_of: Callable[[np.ndarray], SensorModel], theta: np.ndarray,
                 u_prev: np.ndarray) -> np.ndarray:
        """d (u_meas - predict(model_of(theta), u_prev)) / d theta, (3K, p) (M5's residuals).

        A parameter moves the calibrated rate by ``dw = E (w_raw - b) + e`` with ``E = dM``
        and ``e = -M db``; the end orientation then turns by ``dphi = R^T S [E | e]``
        (:meth:`~imucal.numerics.rk4.StepLayout.sensitivity`) and the predicted direction
        ``v = R^T u_prev`` by ``dphi x v``. ``M`` and ``b`` are bilinear in the parameters, so
        central differences of that small map are exact to rounding.
        """
        model = model_of(theta)
        _, S, q = self._sensitivity(model)
        p = len(theta)
        G = np.empty((p, 3, 4))
        for i in range(p):
            h = 1e-4 * max(1.0, abs(float(theta[i])))
            up, dn = theta.copy(), theta.copy()
            up[i] += h
            dn[i] -= h
            mu, md = model_of(up), model_of(dn)
            G[i, :, :3] = (mu.matrix - md.matrix) / (2 * h)
            G[i, :, 3] = -(model.matrix @ (mu.b - md.b)) / (2 * h)
        X = np.einsum("kmij,pij->kmp", S, G)  # integral of R(t) dw(t) dt, per parameter
        R = to_matrix(q)
        dphi = np.einsum("kmn,kmp->knp", R, X)
        v = np.einsum("kmn,km->kn", R, u_prev)
        J = np.cross(dphi, v[:, :, None], axisa=1, axisb=1, axisc=1)
        return J.reshape(-1, p)

    def _slabs(self):
        """Every slab of every bucket: (bucket, its :class:`~imucal.numerics.rk4.lazy.
        LazyRows`, r0, r1)."""
        for bucket, src in zip(self.layout.buckets, self.rates):
            for r0, r1 in slab_ranges(*bucket.dt.shape):
                yield bucket, src, r0, r1

    def max_step_angle(self, model: SensorModel) -> float:
        """Largest angle turned in one step, ``|w(t_n)| dt_n`` with the calibrated rate at the
        step's start (0 without steps)."""
        cal = calibrator([(model.matrix, model.b)])
        out = 0.0
        for _, src, r0, r1 in self._slabs():  # a slab at a time: temporaries stay small
            out = max(out, _step_angle(src.slab(r0, r1), cal))
        return out

    def isotropic(self, bias: np.ndarray):
        """A function of ``s`` giving :meth:`rotations` under the isotropic model ``w = s (w_raw -
        bias)`` (the 1-D scale search runs it dozens of times).

        With ``w = s d`` the closed-form RK4 step (:func:`~imucal.numerics.rk4.rk4_raw`) is a
        polynomial in ``s`` whose coefficients depend on the data only: with ``e = s^2 A``,
        ``P = (1 + e (s^2 B - 1/2), s h/4 (1 - e/6) (d0 + d1) + s^2 h^2/24 (1 - e/4) (d0 x d1))``,
        ``A = h^2 |d0 + d1|^2 / 16`` and ``B = h^2 (d0 . d1) / 96``, made a slab at a time
        (:func:`_isotropic_terms`), so an evaluation costs about two thirds of a general one
        (the products of the steps remain).
        """
        bias = np.asarray(bias, float).tolist()
        n = len(self)

        def rotations(scale: float) -> np.ndarray:
            sc, sc2 = float(scale), float(scale) ** 2
            out = np.empty((n, 4))
            out[:] = (1.0, 0.0, 0.0, 0.0)
            acc = None
            for bucket, src, r0, r1 in self._slabs():
                q = product_rows(_isotropic_step(_isotropic_terms(src.slab(r0, r1), bias),
                                                 sc, sc2))
                acc = q if r0 == 0 else mul(acc, q)
                if r1 == bucket.dt.shape[0]:
                    out[bucket.idx] = np.stack(acc, axis=-1)
            return out / np.linalg.norm(out, axis=-1, keepdims=True)

        return rotations

    def raw_turn(self, bias: np.ndarray) -> np.ndarray:
        """Integral of the norm of the bias-free raw rate over each transition (K,)."""
        out = np.zeros(len(self))
        for bucket, src in zip(self.layout.buckets, self.rates):
            L, kb = bucket.dt.shape
            # np.sum's order over the rows of the whole bucket: pairwise for one column (read
            # whole: one turn's samples), row after row for several (read a slab at a time).
            total = np.zeros(kb)
            for r0, r1 in ([(0, L)] if kb == 1 else slab_ranges(L, kb)):
                f = _raw_turn_rows(src.slab(r0, r1), bias)
                if kb == 1:
                    total = np.sum(f, axis=0)
                    continue
                for row in f:
                    total += row
            out[bucket.idx] = total
        return out


def _step_angle(s: Slab, cal) -> float:
    """The largest ``|w(t_n)| dt_n`` of a slab, the rate calibrated by ``cal``."""
    c = cal(tuple(x[:-1][:, None, :] for x in s.w))
    norm = np.sqrt(c[0] ** 2 + c[1] ** 2 + c[2] ** 2)[:, 0, :]
    return float(np.max(norm * s.dt))


def _raw_turn_rows(s: Slab, bias: np.ndarray) -> np.ndarray:
    """``|mean of two samples - bias| dt`` for every step of a slab (m, K_b)."""
    d = [0.5 * (x[:-1] + x[1:]) - b for x, b in zip(s.w, bias)]
    return np.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2) * s.dt


def _isotropic_terms(s: Slab, bias: list[float]) -> tuple:
    """The data-only coefficients of :meth:`Transitions.isotropic`'s steps for one slab."""
    d = [x - b for x, b in zip(s.w, bias)]
    d0 = [x[:-1] for x in d]
    d1 = [x[1:] for x in d]
    sd = [a + c for a, c in zip(d0, d1)]
    cd = [d0[1] * d1[2] - d0[2] * d1[1], d0[2] * d1[0] - d0[0] * d1[2],
          d0[0] * d1[1] - d0[1] * d1[0]]
    h2 = s.dt2
    A = h2 * (sd[0] * sd[0] + sd[1] * sd[1] + sd[2] * sd[2]) / 16.0
    B = h2 * (d0[0] * d1[0] + d0[1] * d1[1] + d0[2] * d1[2]) / 96.0
    return sd, cd, A, B, s.dt / 4.0, h2 / 24.0


def _isotropic_step(terms: tuple, sc: float, sc2: float) -> tuple:
    """The RK4 steps (unnormalised) of the isotropic model ``w = sc d`` from
    :func:`_isotropic_terms` (M5, :func:`~imucal.numerics.rk4.rk4_raw` in ``sc``)."""
    sd, cd, A, B, h4, h24 = terms
    e = A * sc2
    pw = B * sc2
    pw -= 0.5
    pw *= e
    pw += 1.0
    al = e * (-1.0 / 6.0)
    al += 1.0
    al *= h4
    al *= sc
    be = e * -0.25
    be += 1.0
    be *= h24
    be *= sc2
    pv = []
    for i in range(3):
        v = sd[i] * al
        v += cd[i] * be
        pv.append(v)
    return (pw, *pv)


def gyro_model_of(theta: np.ndarray, static_bias: np.ndarray, s0: float) -> SensorModel:
    """M4 in raw units from the fit's parameters: 6 misalignments, 3 scales relative to the
    nominal scale ``s0`` and, when there are 12, a bias correction in nominal rad/s on top of
    the static bias."""
    b = static_bias + (theta[9:12] / s0 if len(theta) > 9 else 0.0)
    return SensorModel(T=gyro_T(theta), K=np.asarray(theta[6:9], float) * s0,
                       b=np.asarray(b, float))


def angle_between(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Angle in degrees between rows of u and v (atan2 form: exact for small angles)."""
    c = np.linalg.norm(np.cross(u, v), axis=-1)
    d = np.einsum("ij,ij->i", u, v)
    return np.degrees(np.arctan2(c, d))
