"""imucal.numerics.rk4.step: the closed-form step against the four RK4 stages written out."""

import numpy as np
import pytest

from imucal.numerics import quaternion as quat
from imucal.numerics.rk4.step import rk4_raw, rk4_step_quaternions, rk4_steps


def _stages(w0: np.ndarray, w1: np.ndarray, h: float) -> np.ndarray:
    """One unnormalised RK4 step from q = 1 with the half-step rate the mean of the ends."""
    q = np.array([1.0, 0.0, 0.0, 0.0])

    def f(q, w):
        return 0.5 * quat.multiply(q, np.r_[0.0, w])

    wm = 0.5 * (w0 + w1)
    k1 = f(q, w0)
    k2 = f(q + h / 2 * k1, wm)
    k3 = f(q + h / 2 * k2, wm)
    k4 = f(q + h * k3, w1)
    return q + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


@pytest.mark.parametrize("scale, h", [(0.1, 0.01), (3.0, 0.01), (10.0, 0.05), (1.0, 1.0)])
def test_closed_form_equals_the_stages(scale, h):
    rng = np.random.default_rng(int(scale * 10))
    w0, w1 = scale * rng.normal(size=(50, 3)), scale * rng.normal(size=(50, 3))
    hs = h * rng.uniform(0.5, 1.5, 50)
    got = np.stack(rk4_raw(tuple(w0.T.copy()), tuple(w1.T.copy()), hs), axis=-1)
    ref = np.array([_stages(a, b, dt) for a, b, dt in zip(w0, w1, hs)])
    np.testing.assert_allclose(got, ref, rtol=1e-13, atol=1e-15)


def test_precomputed_h2_gives_the_same_step():
    rng = np.random.default_rng(4)
    w0, w1, h = tuple(rng.normal(size=(3, 9))), tuple(rng.normal(size=(3, 9))), rng.random(9)
    a = np.stack(rk4_raw(tuple(c.copy() for c in w0), tuple(c.copy() for c in w1), h))
    b = np.stack(rk4_raw(w0, w1, h, h * h))
    np.testing.assert_array_equal(a, b)


def test_a_step_of_zero_length_is_exactly_the_identity():
    rng = np.random.default_rng(5)
    w0, w1 = tuple(100 * rng.normal(size=(3, 8))), tuple(100 * rng.normal(size=(3, 8)))
    got = np.stack(rk4_raw(w0, w1, np.zeros(8)), axis=-1)
    np.testing.assert_array_equal(got, np.tile([1.0, 0, 0, 0], (8, 1)))


def test_constant_rate_is_the_exponential_to_fourth_order():
    w = np.array([0.3, -1.2, 2.0])
    for h in (0.02, 0.01):
        P = rk4_step_quaternions(w[None], w[None], np.array([h]))[0]
        # the local error of RK4 is O(h^5): (|w| h / 2)^5 / 120 bounds it here
        bound = (np.linalg.norm(w) * h / 2) ** 5 / 120 + 1e-16
        assert np.abs(P - quat.from_rotvec(w * h)).max() < 2 * bound


def test_steps_are_unit_and_shaped_like_their_rates():
    rng = np.random.default_rng(6)
    w0, w1, h = rng.normal(size=(4, 5, 3)), rng.normal(size=(4, 5, 3)), rng.random((4, 5))
    P = rk4_step_quaternions(w0, w1, h)
    assert P.shape == (4, 5, 4)
    np.testing.assert_allclose(np.linalg.norm(P, axis=-1), 1.0, rtol=1e-15)
    raw = np.stack(rk4_raw(tuple(np.moveaxis(w0, -1, 0)), tuple(np.moveaxis(w1, -1, 0)), h), -1)
    np.testing.assert_allclose(P, raw / np.linalg.norm(raw, axis=-1, keepdims=True), rtol=1e-15)
    np.testing.assert_array_equal(np.stack(rk4_steps(tuple(np.moveaxis(w0, -1, 0)),
                                                     tuple(np.moveaxis(w1, -1, 0)), h), -1), P)
