"""imucal.numerics.rk4.kernels: every interval's rotation against the RK4 loop written out,
under one model, several and one per interval; the largest step and the raw turn against numpy
written out."""

import numpy as np
import pytest

from imucal.numerics import quaternion as quat
from imucal.numerics.rk4 import kernels


@pytest.fixture
def recording():
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.008, 0.012, 3000))
    w = np.column_stack([2 * np.sin(t * f + p) for f, p in ((1.3, 0), (0.7, 1), (2.1, 2))])
    w += 0.1 * rng.normal(size=w.shape)
    # lengths from 0 to 2500 steps, overlapping, one ending at the last sample
    starts = np.array([0, 10, 300, 1000, 2990, 400, 1500, 2994], np.int64)
    ends = np.array([2500, 40, 350, 1003, 2990, 1800, 1510, 2999], np.int64)
    return t, w, starts, ends


def _models(n, seed=4):
    rng = np.random.default_rng(seed)
    return (np.eye(3) + 0.05 * rng.normal(size=(n, 3, 3)), 0.1 * rng.normal(size=(n, 3)))


def _integrate(t, w, starts, ends, M, b):
    out = np.full((len(M), len(starts), 4), np.nan)
    kernels.integrate(w, t, starts, ends, M, b, out)
    return out


def test_each_interval_is_the_rk4_loop(recording, sequential, assert_same_rotation):
    t, w, starts, ends = recording
    got = _integrate(t, w, starts, ends, np.eye(3)[None], np.zeros((1, 3)))[0]
    for q, s, e in zip(got, starts, ends):
        assert_same_rotation(q, sequential(w[s:e + 1], t[s:e + 1])[-1], atol=1e-11)
    np.testing.assert_array_equal(got[4], [1.0, 0.0, 0.0, 0.0])  # no step: no rotation
    np.testing.assert_allclose(np.linalg.norm(got, axis=1), 1.0, rtol=1e-15)


def test_models_are_applied_and_each_is_computed_as_alone(recording, assert_same_rotation):
    t, w, starts, ends = recording
    M, b = _models(3)
    together = _integrate(t, w, starts, ends, M, b)
    for i in range(3):
        alone = _integrate(t, w, starts, ends, M[i:i + 1], b[i:i + 1])[0]
        np.testing.assert_array_equal(together[i], alone)
        calibrated = (w - b[i]) @ M[i].T
        ref = _integrate(t, calibrated, starts, ends, np.eye(3)[None], np.zeros((1, 3)))[0]
        assert_same_rotation(alone, ref, atol=1e-12)


def test_a_model_per_interval_is_each_model_alone(recording):
    t, w, starts, ends = recording
    M, b = _models(len(starts), seed=5)
    got = np.full((len(starts), 4), np.nan)
    kernels.integrate_each(w, t, starts, ends, M, b, got)
    every = _integrate(t, w, starts, ends, M, b)
    np.testing.assert_array_equal(got, every[np.arange(len(starts)), np.arange(len(starts))])


def test_a_constant_rate_over_many_samples_is_the_exact_rotation():
    n = 40000
    rng = np.random.default_rng(5)
    t = np.cumsum(rng.uniform(0.008, 0.012, n + 1))
    rate = np.array([0.2, -0.4, 0.3])
    w = np.tile(rate, (n + 1, 1))
    got = _integrate(t, w, np.array([0]), np.array([n]), np.eye(3)[None], np.zeros((1, 3)))
    # the local error of a step, (|w| h / 2)^5 / 120 ~ 1e-17, is below rounding
    exact = quat.from_rotvec(rate * (t[-1] - t[0]))
    np.testing.assert_allclose(got[0, 0] * np.sign(got[0, 0, 0] * exact[0]), exact, atol=1e-11)


def test_the_largest_step_and_the_raw_turn(recording):
    t, w, starts, ends = recording
    M, b = _models(1, seed=6)
    c = (w - b[0]) @ M[0].T
    angle = np.linalg.norm(c[:-1], axis=1) * np.diff(t)
    steps = np.concatenate([np.arange(s, e) for s, e in zip(starts, ends)])
    got = kernels.max_step(w, t, starts, ends, M[0], b[0])
    assert got == pytest.approx(angle[steps].max(), rel=1e-14)
    assert kernels.max_step(w, t, starts[4:5], ends[4:5], M[0], b[0]) == 0.0  # no step
    turn = np.full(len(starts), np.nan)
    kernels.raw_turn(w, t, starts, ends, b[0], turn)
    rate = np.linalg.norm(0.5 * (w[:-1] + w[1:]) - b[0], axis=1) * np.diff(t)
    np.testing.assert_allclose(turn, [rate[s:e].sum() for s, e in zip(starts, ends)],
                               rtol=1e-13)
    assert turn[4] == 0.0
