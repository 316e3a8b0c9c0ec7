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
from imucal.numerics.rk4 import SLAB, StepLayout, calibrator, mul, product_rows
from imucal.numerics.rk4.integrate import integrate_buckets


def transition_samples(t: np.ndarray, block_times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gyroscope sample indices bracketing each transition: from just before the end of block k
    to just after the start of block k+1."""
    s = np.clip(np.searchsorted(t, block_times[:-1, 1], side="left") - 1, 0, len(t) - 1)
    e = np.clip(np.searchsorted(t, block_times[1:, 0], side="right"), 0, len(t) - 1)
    return s, np.maximum(e, s)


class Transitions:
    """The gyroscope samples of every motion between consecutive static blocks, laid out once.

    Transition k runs from the end of block k to the start of block k+1. Its RK4 steps are laid
    out time-major with the other transitions of similar length (:class:`StepLayout`; identity
    steps pad the shorter ones), so every cost evaluation is a handful of vector operations over
    all transitions (M5), and the model is applied to the raw rates slab by slab, each slab
    gathered from the session's array when it is read (only a slab of the turns is held).
    """

    def __init__(self, w_raw: np.ndarray, t: np.ndarray, block_times: np.ndarray,
                 keep: np.ndarray | None = None):
        s, e = transition_samples(t, block_times)
        if keep is not None:  # only these transitions (a boolean mask over all of them)
            s, e = s[keep], e[keep]
        self.starts, self.ends = s, e
        self.n_steps = e - s
        # Nothing the size of the turns is kept: each slab of samples (and of step times) is
        # gathered from the session's columns when an integration or the Jacobian reads it
        # (numerics/rk4/lazy.py; the same values to the bit as gathered once).
        self.layout = StepLayout(t, s, e, lazy=True)
        self.rates = self.layout.lazy_samples([w_raw[:, i] for i in range(3)])

    def __len__(self) -> int:
        return len(self.starts)

    def rotations(self, model: SensorModel) -> np.ndarray:
        """Quaternion of the body rotation over each transition under ``model`` (K, 4)."""
        return self.rotations_many([model])[0]

    def rotations_many(self, models: list[SensorModel]) -> np.ndarray:
        """:meth:`rotations` for several models in one pass (k, K, 4)."""
        return self.layout.integrate(self.rates, [(m.matrix, m.b) for m in models])

    def predict(self, model: SensorModel, u_prev: np.ndarray) -> np.ndarray:
        """M5: gravity of block k-1 carried into the body frame of block k, ``R_k^T u_(k-1)``."""
        return rotate_inverse(self.rotations(model), u_prev)

    def rotations_each(self, M: np.ndarray, b: np.ndarray) -> np.ndarray:
        """:meth:`rotations` with a model of its own for each transition, ``w = M[k] (w_raw -
        b[k])`` over transition k ((K, 3, 3) and (K, 3)); (K, 4). One evaluation's work: the
        cross-validation predicts each held-out turn with its own fold's fit this way."""
        out = np.empty((len(self), 4))
        for bucket, w in zip(self.layout.buckets, self.rates):
            Mk, bk = M[bucket.idx], b[bucket.idx]  # one column of the bucket per transition

            def cal(x, Mk=Mk, bk=bk):  # a slab of rows at a time, not the bucket at once
                d = [v[:, 0] - bk[:, j] for j, v in enumerate(x)]
                return tuple((d[0] * Mk[:, i, 0] + d[1] * Mk[:, i, 1] + d[2] * Mk[:, i, 2]
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
        q, S = self.layout.sensitivity(self.rates, model.matrix, model.b)
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

    def max_step_angle(self, model: SensorModel) -> float:
        """Largest angle turned in one step, ``|w(t_n)| dt_n`` with the calibrated rate at the
        step's start (0 without steps)."""
        cal = calibrator([(model.matrix, model.b)])
        out = 0.0
        for (_, _, _, dt, _), w in zip(self.layout.buckets, self.rates):
            rows = max(1, SLAB // max(dt.shape[1], 1))  # a slab at a time: temporaries stay small
            for r0 in range(0, dt.shape[0] if dt.size else 0, rows):
                sl = slice(r0, min(r0 + rows, dt.shape[0]))
                c = cal(tuple(x[sl][:, None, :] for x in w))
                norm = np.sqrt(c[0] ** 2 + c[1] ** 2 + c[2] ** 2)[:, 0, :]
                out = max(out, float(np.max(norm * dt[sl])))
        return out

    def isotropic(self, bias: np.ndarray):
        """A function of ``s`` giving :meth:`rotations` under the isotropic model ``w = s (w_raw -
        bias)`` (the 1-D scale search runs it dozens of times).

        With ``w = s d`` the closed-form RK4 step (:func:`~imucal.numerics.rk4.rk4_raw`) is a
        polynomial in ``s`` whose coefficients depend on the data only: with ``e = s^2 A``,
        ``P = (1 + e (s^2 B - 1/2), s h/4 (1 - e/6) (d0 + d1) + s^2 h^2/24 (1 - e/4) (d0 x d1))``,
        ``A = h^2 |d0 + d1|^2 / 16`` and ``B = h^2 (d0 . d1) / 96``, all precomputed here, so an
        evaluation costs about two thirds of a general one (the products of the steps remain).
        """
        bias = np.asarray(bias, float).tolist()
        n = len(self)

        def slab(w, dt, dt2, sl: slice) -> tuple:
            # The data-only coefficients of rows ``sl`` of the steps, made when used (a slab of
            # the turns at a time), the same values as made for the whole bucket at once.
            d = [x[sl.start:sl.stop + 1] - b for x, b in zip(w, bias)]
            d0 = [x[:-1] for x in d]
            d1 = [x[1:] for x in d]
            sd = [a + c for a, c in zip(d0, d1)]
            cd = [d0[1] * d1[2] - d0[2] * d1[1], d0[2] * d1[0] - d0[0] * d1[2],
                  d0[0] * d1[1] - d0[1] * d1[0]]
            h2 = dt2[sl]
            A = h2 * (sd[0] * sd[0] + sd[1] * sd[1] + sd[2] * sd[2]) / 16.0
            B = h2 * (d0[0] * d1[0] + d0[1] * d1[1] + d0[2] * d1[2]) / 96.0
            return sd, cd, A, B, dt[sl] / 4.0, h2 / 24.0

        def rotations(scale: float) -> np.ndarray:
            sc, sc2 = float(scale), float(scale) ** 2
            out = np.empty((n, 4))
            out[:] = (1.0, 0.0, 0.0, 0.0)
            for (idx, _, _, dt, dt2), w in zip(self.layout.buckets, self.rates):
                L, kb = dt.shape
                rows = max(1, SLAB // max(kb, 1))
                acc = None
                for r0 in range(0, L, rows):
                    sd, cd, A, B, h4, h24 = slab(w, dt, dt2, slice(r0, min(r0 + rows, L)))
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
                    q = product_rows((pw, *pv))
                    acc = q if acc is None else mul(acc, q)
                out[idx] = np.stack(acc, axis=-1)
            return out / np.linalg.norm(out, axis=-1, keepdims=True)

        return rotations

    def raw_turn(self, bias: np.ndarray) -> np.ndarray:
        """Integral of the norm of the bias-free raw rate over each transition (K,)."""
        out = np.zeros(len(self))
        for (idx, _, _, dt, _), w in zip(self.layout.buckets, self.rates):
            # A bucket at a time, whole (np.sum's order over rows): run once, before the fit.
            w = [x[:] for x in w]
            d = [0.5 * (x[:-1] + x[1:]) - b for x, b in zip(w, bias)]
            out[idx] = np.sum(np.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2) * dt[:], axis=0)
        return out


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
