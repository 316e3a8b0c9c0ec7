"""imucal.numerics.rk4.variational: ``S`` against the trapezoid sum written out, and the
rotation it predicts for a change of the model against finite differences of the integration."""

import numpy as np
import pytest

from imucal.numerics import quaternion as quat
from imucal.numerics.rk4.buckets import lay_out, length_buckets
from imucal.numerics.rk4.integrate import SLAB, integrate_buckets
from imucal.numerics.rk4.variational import sensitivity, trapezoid_weights


def _setup(t, w, starts, ends):
    n_steps = ends - starts
    buckets = [lay_out(t, starts, n_steps, idx) for idx in length_buckets(n_steps)]
    samples = [tuple(np.where(b.valid, w[:, j][b.i0], 0.0) for j in range(3)) for b in buckets]
    return buckets, samples


def _recording(n, seed=0):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.008, 0.012, n))
    w = np.column_stack([1.5 * np.sin(t * f + p) for f, p in ((1.1, 0), (0.6, 1), (1.9, 2))])
    return t, w + 0.05 * rng.normal(size=w.shape)


@pytest.fixture
def model():
    rng = np.random.default_rng(1)
    return np.eye(3) + 0.05 * rng.normal(size=(3, 3)), 0.02 * rng.normal(size=3)


def test_S_is_the_trapezoid_integral_of_R_times_d(model, sequential):
    t, w = _recording(400)
    starts, ends = np.array([0, 100, 250]), np.array([90, 300, 250])
    M, b = model
    buckets, samples = _setup(t, w, starts, ends)
    q, S, _ = sensitivity(buckets, 3, samples, M, b)
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


def _rotation_change(q, S, G):
    """dphi = R(q)^T sum_ij S[:, :, i, j] G[i, j] (body frame), per interval."""
    X = np.einsum("kmij,ij->km", S, G)
    return np.einsum("kmn,km->kn", quat.to_matrix(q), X)


def _finite_difference(buckets, samples, n, q, M, b, dM, db, eps=1e-6):
    out = []
    for sign in (1, -1):
        qe = integrate_buckets(buckets, n, samples, [(M + sign * eps * dM, b + sign * eps * db)])
        out.append(quat.to_rotvec(quat.multiply(quat.conjugate(q), qe[0])))
    return (out[0] - out[1]) / (2 * eps)


@pytest.mark.parametrize("long", [False, True])
def test_the_predicted_rotation_change_matches_finite_differences(model, long):
    # long: one interval of more rows than a slab, so the carried rotation is exercised
    n = SLAB + 3000 if long else 3000
    t, w = _recording(n + 1, seed=2)
    starts = np.array([0, 500, 1200] + ([5] if long else []))
    ends = np.array([400, 1100, 2900] + ([n] if long else []))
    M, b = model
    buckets, samples = _setup(t, w, starts, ends)
    q, S, _ = sensitivity(buckets, len(starts), samples, M, b)
    rng = np.random.default_rng(3)
    for _ in range(3):
        dM, db = rng.normal(size=(3, 3)), rng.normal(size=3)
        G = np.column_stack([dM, -M @ db])  # dw = dM (w_raw - b) - M db
        got = _rotation_change(q, S, G)
        ref = _finite_difference(buckets, samples, len(starts), q, M, b, dM, db)
        # the trapezoid rule's relative error is about (w h)^2 / 12 per step
        scale = np.linalg.norm(ref, axis=1, keepdims=True)
        assert np.all(np.abs(got - ref) <= 1e-3 * scale + 1e-9)
        assert np.all(scale > 1e-2)  # a change that moves something


@pytest.mark.parametrize("long", [False, True])
def test_the_rotation_is_the_integrations_to_the_bit_and_the_scans_to_rounding(model, long):
    # one pass makes a fit's residuals and its Jacobian: its rotation must be the one the
    # integration alone gives, whatever the slabs (long: an interval over several)
    n = SLAB + 3000 if long else 3000
    t, w = _recording(n + 1, seed=4)
    starts = np.array([0, 500, 1200, 7] + ([5] if long else []))
    ends = np.array([400, 1100, 2900, 7] + ([n] if long else []))
    M, b = model
    buckets, samples = _setup(t, w, starts, ends)
    q, _, q_scan = sensitivity(buckets, len(starts), samples, M, b)
    np.testing.assert_array_equal(q, integrate_buckets(buckets, len(starts), samples,
                                                       [(M, b)])[0])
    np.testing.assert_allclose(q_scan, q, rtol=0, atol=1e-12)


def test_trapezoid_weights_sum_to_the_duration_and_carry_d():
    t = np.array([0.0, 0.1, 0.3, 0.6])
    dt = np.diff(t)[:, None] * np.ones((1, 2))
    dt[2, 1] = 0.0  # the second interval is one step shorter (padding)
    w = tuple(np.arange(8.0).reshape(4, 2) + j for j in range(3))
    W = trapezoid_weights(w, [1.0, 2.0, 3.0], dt)
    assert W.shape == (2, 4, 4)
    np.testing.assert_allclose(W[:, :, 3].sum(axis=1), [0.6, 0.3])
    np.testing.assert_allclose(W[0, :, 3], [0.05, 0.15, 0.25, 0.15])
    np.testing.assert_allclose(W[0, :, 0], W[0, :, 3] * (w[0][:, 0] - 1.0))
    np.testing.assert_allclose(W[1, :, 2], W[1, :, 3] * (w[2][:, 1] - 3.0))
