"""imucal.numerics.rk4.integrate: every interval's rotation against the RK4 loop written out,
and against the exact rotation of a constant rate over more rows than one slab."""

import numpy as np
import pytest

from imucal.numerics import quaternion as quat
from imucal.numerics.rk4.buckets import lay_out, length_buckets
from imucal.numerics.rk4.integrate import SLAB, integrate_buckets


def _buckets(t, starts, ends):
    n_steps = ends - starts
    return [lay_out(t, starts, n_steps, idx) for idx in length_buckets(n_steps)]


def _gather(buckets, w):
    return [tuple(np.where(b.valid, w[:, j][b.i0], 0.0) for j in range(3)) for b in buckets]


@pytest.fixture
def recording():
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.008, 0.012, 3000))
    w = np.column_stack([2 * np.sin(t * f + p) for f, p in ((1.3, 0), (0.7, 1), (2.1, 2))])
    w += 0.1 * rng.normal(size=w.shape)
    # lengths from 0 to 2500 steps: several buckets (twenty short turns would pad 50000 steps
    # in the long one's), identity padding, an empty interval
    short = np.arange(2000, 2800, 40)
    starts = np.r_[0, 10, 300, 1000, 2990, 400, 1500, short]
    ends = np.r_[2500, 40, 350, 1003, 2990, 1800, 1510, short + 5]
    return t, w, starts, ends


def test_each_interval_is_the_rk4_loop(recording, sequential, assert_same_rotation):
    t, w, starts, ends = recording
    buckets = _buckets(t, starts, ends)
    assert len(buckets) > 1
    got = integrate_buckets(buckets, len(starts), _gather(buckets, w))
    assert got.shape == (1, len(starts), 4)
    for q, s, e in zip(got[0], starts, ends):
        assert_same_rotation(q, sequential(w[s:e + 1], t[s:e + 1])[-1], atol=1e-11)


def test_models_are_applied_and_each_is_computed_as_alone(recording):
    t, w, starts, ends = recording
    buckets = _buckets(t, starts, ends)
    rng = np.random.default_rng(4)
    models = [(np.eye(3) + 0.05 * rng.normal(size=(3, 3)), 0.1 * rng.normal(size=3))
              for _ in range(3)]
    together = integrate_buckets(buckets, len(starts), _gather(buckets, w), models)
    for i, (M, b) in enumerate(models):
        alone = integrate_buckets(buckets, len(starts), _gather(buckets, w), [(M, b)])[0]
        np.testing.assert_array_equal(together[i], alone)
        calibrated = (w - b) @ M.T
        ref = integrate_buckets(buckets, len(starts), _gather(buckets, calibrated))[0]
        np.testing.assert_allclose(alone * np.sign(alone[:, :1]), ref * np.sign(ref[:, :1]),
                                   atol=1e-12)


def test_a_constant_rate_over_many_slabs_is_the_exact_rotation():
    # One interval longer than a slab: the slabs' products are carried into each other.
    n = SLAB + 7000
    rng = np.random.default_rng(5)
    t = np.cumsum(rng.uniform(0.008, 0.012, n + 1))
    rate = np.array([0.2, -0.4, 0.3])
    w = np.tile(rate, (n + 1, 1))
    buckets = _buckets(t, np.array([0]), np.array([n]))
    got = integrate_buckets(buckets, 1, _gather(buckets, w))[0, 0]
    # the local error of a step, (|w| h / 2)^5 / 120 ~ 1e-17, is below rounding
    exact = quat.from_rotvec(rate * (t[-1] - t[0]))
    np.testing.assert_allclose(got * np.sign(got[0] * exact[0]), exact, atol=1e-11)
