"""imucal.numerics.rk4.kernels.sensitivity: ``S`` against the trapezoid sum written out, the
rotation it predicts for a change of the model against finite differences of the integration,
and its rotation against the integration's, to the bit."""

import numpy as np
import pytest

from imucal.numerics import quaternion as quat
from imucal.numerics.rk4 import kernels


def _recording(n, seed=0):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.008, 0.012, n))
    w = np.column_stack([1.5 * np.sin(t * f + p) for f, p in ((1.1, 0), (0.6, 1), (1.9, 2))])
    return t, w + 0.05 * rng.normal(size=w.shape)


@pytest.fixture
def model():
    rng = np.random.default_rng(1)
    return np.eye(3) + 0.05 * rng.normal(size=(3, 3)), 0.02 * rng.normal(size=3)


def _sensitivity(t, w, starts, ends, M, b):
    q, S = np.full((len(starts), 4), np.nan), np.full((len(starts), 9, 4), np.nan)
    kernels.sensitivity(w, t, starts, ends, M, b, q, S)
    return q, S.reshape(-1, 3, 3, 4)


def _integrate(t, w, starts, ends, M, b):
    out = np.empty((1, len(starts), 4))
    kernels.integrate(w, t, starts, ends, M[None], b[None], out)
    return out[0]


def test_S_is_the_trapezoid_integral_of_R_times_d(model, sequential):
    t, w = _recording(400)
    starts, ends = np.array([0, 100, 250]), np.array([90, 300, 250])
    M, b = model
    q, S = _sensitivity(t, w, starts, ends, M, b)
    for k, (s, e) in enumerate(zip(starts, ends)):
        Q = sequential((w[s:e + 1] - b) @ M.T, t[s:e + 1])  # orientation at every sample
        R = quat.to_matrix(Q)
        h = np.diff(t[s:e + 1])
        c = np.zeros(e - s + 1)
        c[:-1] += h / 2
        c[1:] += h / 2
        d = np.column_stack([w[s:e + 1] - b, np.ones(e - s + 1)])
        ref = np.einsum("n,nmi,nj->mij", c, R, d)
        np.testing.assert_allclose(S[k], ref, atol=1e-12)
        np.testing.assert_allclose(q[k] * np.sign(q[k, 0]), Q[-1] * np.sign(Q[-1, 0]),
                                   atol=1e-12)
    np.testing.assert_array_equal(S[2], 0.0)  # no step: no time


def _rotation_change(q, S, G):
    """dphi = R(q)^T sum_ij S[:, :, i, j] G[i, j] (body frame), per interval."""
    X = np.einsum("kmij,ij->km", S, G)
    return np.einsum("kmn,km->kn", quat.to_matrix(q), X)


def test_the_predicted_rotation_change_matches_finite_differences(model):
    n = 40000  # one interval of many samples among short ones
    t, w = _recording(n + 1, seed=2)
    starts, ends = np.array([0, 500, 1200, 5]), np.array([400, 1100, 2900, n])
    M, b = model
    q, S = _sensitivity(t, w, starts, ends, M, b)
    rng = np.random.default_rng(3)
    eps = 1e-6
    for _ in range(3):
        dM, db = rng.normal(size=(3, 3)), rng.normal(size=3)
        G = np.column_stack([dM, -M @ db])  # dw = dM (w_raw - b) - M db
        got = _rotation_change(q, S, G)
        moved = [_integrate(t, w, starts, ends, M + s * eps * dM, b + s * eps * db)
                 for s in (1, -1)]
        ref = np.diff([quat.to_rotvec(quat.multiply(quat.conjugate(q), qe))
                       for qe in moved[::-1]], axis=0)[0] / (2 * eps)
        # the trapezoid rule's relative error is about (w h)^2 / 12 per step
        scale = np.linalg.norm(ref, axis=1, keepdims=True)
        assert np.all(np.abs(got - ref) <= 1e-3 * scale + 1e-9)
        assert np.all(scale > 1e-2)  # a change that moves something


def test_the_rotation_is_the_integrations_to_the_bit(model):
    # one pass makes a fit's residuals and its Jacobian: its rotation must be the one the
    # integration alone gives
    t, w = _recording(3001, seed=4)
    starts, ends = np.array([0, 500, 1200, 7]), np.array([400, 1100, 3000, 7])
    M, b = model
    q, _ = _sensitivity(t, w, starts, ends, M, b)
    np.testing.assert_array_equal(q, _integrate(t, w, starts, ends, M, b))
