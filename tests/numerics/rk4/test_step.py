"""imucal.numerics.rk4.step: the closed-form RK4 step against the four stages written out, and
the Hamilton product and rotation matrix against scipy."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from imucal.numerics import quaternion as quat
from imucal.numerics.rk4.step import calibrated, hamilton, rk4_step, rotation_matrix


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
    got = np.array([rk4_step(*a, *b, dt) for a, b, dt in zip(w0, w1, hs)])
    ref = np.array([_stages(a, b, dt) for a, b, dt in zip(w0, w1, hs)])
    np.testing.assert_allclose(got, ref, rtol=1e-13, atol=1e-15)


def test_a_step_of_zero_length_is_exactly_the_identity():
    rng = np.random.default_rng(5)
    for a, b in zip(100 * rng.normal(size=(8, 3)), 100 * rng.normal(size=(8, 3))):
        assert rk4_step(*a, *b, 0.0) == (1.0, 0.0, 0.0, 0.0)


def test_constant_rate_is_the_exponential_to_fourth_order():
    w = np.array([0.3, -1.2, 2.0])
    for h in (0.02, 0.01):
        P = np.array(rk4_step(*w, *w, h))
        P /= np.linalg.norm(P)
        # the local error of RK4 is O(h^5): (|w| h / 2)^5 / 120 bounds it here
        bound = (np.linalg.norm(w) * h / 2) ** 5 / 120 + 1e-16
        assert np.abs(P - quat.from_rotvec(w * h)).max() < 2 * bound


def test_the_affine_model_is_M_times_w_minus_b():
    rng = np.random.default_rng(6)
    w, M, b = rng.normal(size=(4, 3)), rng.normal(size=(3, 3)), rng.normal(size=3)
    got = np.array(calibrated(w, 2, M, b))
    np.testing.assert_allclose(got[:3], M @ (w[2] - b), rtol=1e-14)
    np.testing.assert_array_equal(got[3:], w[2] - b)


def test_hamilton_product_is_the_composition_of_rotations():
    rng = np.random.default_rng(7)
    for p, q in zip(rng.normal(size=(10, 4)), rng.normal(size=(10, 4))):
        np.testing.assert_allclose(hamilton(*p, *q), quat.multiply(p, q), rtol=1e-14,
                                   atol=1e-15)
    p, q = quat.normalize(rng.normal(size=(2, 4)))
    ref = (Rotation.from_quat(np.roll(p, -1)) * Rotation.from_quat(np.roll(q, -1))).as_quat()
    got = np.roll(hamilton(*p, *q), -1)
    np.testing.assert_allclose(got * np.sign(got[3] * ref[3]), ref, atol=1e-14)


def test_rotation_matrix_of_a_quaternion_of_any_norm():
    rng = np.random.default_rng(8)
    for q in rng.normal(size=(20, 4)) * rng.uniform(0.5, 2.0, (20, 1)):
        ref = Rotation.from_quat(np.roll(q, -1)).as_matrix().ravel()
        np.testing.assert_allclose(rotation_matrix(*q), ref, atol=1e-14)
