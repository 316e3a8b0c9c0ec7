"""The motions between still poses, integrated (method.md §4, M5): each transition's gyroscope
samples are where they lie in the session's arrays, and every evaluation of the gyroscope cost
integrates all of them (RK4 on quaternions, a compiled loop over each turn's samples:
:mod:`imucal.numerics.rk4`), with its sensitivity to the parameters when asked.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from imucal.models import SensorModel, gyro_T
from imucal.numerics.quaternion import rotate_inverse, to_matrix
from imucal.numerics.rk4 import Intervals, Sensitivity


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
    """The gyroscope samples of every motion between consecutive static blocks.

    Transition k runs from the end of block k to the start of block k+1: ``ends[k] -
    starts[k]`` RK4 steps from sample ``starts[k]`` (M5), integrated by a compiled loop over
    its samples (:class:`~imucal.numerics.rk4.Intervals`), read where they lie in the session's
    arrays (a float64 ndarray, memory-mapped or not) or gathered a chunk of turns at a time.

    ``w_raw`` (N, 3) and ``t`` (N,) are otherwise read only by ``len``, ``.shape`` and gathers
    of rows with a 1-D integer array (they may be arrays kept on disk).
    """

    def __init__(self, w_raw, t, block_times: np.ndarray, keep: np.ndarray | None = None):
        s, e = transition_samples(t, block_times)
        if keep is not None:  # only these transitions (a boolean mask over all of them)
            s, e = s[keep], e[keep]
        self.starts, self.ends = s, e
        self.n_steps = e - s
        self.turns = Intervals(w_raw, t, s, e)
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
        the samples are then read once for both; the rotations are the same to the bit). A
        model integrated lately is not integrated again (the same numbers)."""
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
            self._latest = (key, self.turns.sensitivity(model.matrix, model.b))
        self._keep(key, self._latest[1].q)
        return self._latest[1]

    def rotations_many(self, models: list[SensorModel]) -> np.ndarray:
        """:meth:`rotations` for several models in one pass (k, K, 4), each model's the same
        as alone (the scale search evaluates its grid this way)."""
        return self.turns.integrate(np.array([m.matrix for m in models]).reshape(-1, 3, 3),
                                    np.array([m.b for m in models]).reshape(-1, 3))

    def predict(self, model: SensorModel, u_prev: np.ndarray, sensitivity: bool = False
                ) -> np.ndarray:
        """M5: gravity of block k-1 carried into the body frame of block k, ``R_k^T u_(k-1)``
        (``sensitivity``: see :meth:`rotations`)."""
        return rotate_inverse(self.rotations(model, sensitivity), u_prev)

    def rotations_each(self, M: np.ndarray, b: np.ndarray) -> np.ndarray:
        """:meth:`rotations` with a model of its own for each transition, ``w = M[k] (w_raw -
        b[k])`` over transition k ((K, 3, 3) and (K, 3)); (K, 4). One evaluation's work: the
        cross-validation predicts each held-out turn with its own fold's fit this way."""
        return self.turns.integrate_each(M, b)

    def jacobian(self, model_of: Callable[[np.ndarray], SensorModel], theta: np.ndarray,
                 u_prev: np.ndarray) -> np.ndarray:
        """d (u_meas - predict(model_of(theta), u_prev)) / d theta, (3K, p) (M5's residuals).

        A parameter moves the calibrated rate by ``dw = E (w_raw - b) + e`` with ``E = dM``
        and ``e = -M db``; the end orientation then turns by ``dphi = R^T S [E | e]``
        (:meth:`~imucal.numerics.rk4.Intervals.sensitivity`) and the predicted direction
        ``v = R^T u_prev`` by ``dphi x v``. ``M`` and ``b`` are bilinear in the parameters, so
        central differences of that small map are exact to rounding.
        """
        model = model_of(theta)
        q, S = self._sensitivity(model)
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
        return self.turns.max_step(model.matrix, model.b)

    def raw_turn(self, bias: np.ndarray) -> np.ndarray:
        """Integral of the norm of the bias-free raw rate over each transition (K,)."""
        return self.turns.raw_turn(bias)


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
