"""imucal.numerics.quaternion against scipy's Rotation (scalar last there, scalar first here)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from imucal.numerics import quaternion as quat


def _scipy(q: np.ndarray) -> Rotation:
    return Rotation.from_quat(np.roll(q, -1, axis=-1))


def _same_rotation(q: np.ndarray, ref: np.ndarray, atol: float) -> None:
    """q and -q are the same rotation: compare after putting both in the w >= 0 half."""
    np.testing.assert_allclose(q * np.sign(q[..., :1]), ref * np.sign(ref[..., :1]), atol=atol)


@pytest.fixture
def rng():
    return np.random.default_rng(11)


def test_multiply_is_the_composition_of_rotations(rng):
    p, q = quat.random_unit(50, rng), quat.random_unit(50, rng)
    ref = np.roll((_scipy(p) * _scipy(q)).as_quat(), 1, axis=-1)
    _same_rotation(quat.multiply(p, q), ref, 1e-14)
    np.testing.assert_allclose(quat.to_matrix(quat.multiply(p, q)),
                               quat.to_matrix(p) @ quat.to_matrix(q), atol=1e-14)


def test_multiply_broadcasts_and_is_not_commutative(rng):
    p, q = quat.random_unit(1, rng), quat.random_unit(5, rng)
    assert quat.multiply(p, q).shape == (5, 4)
    assert np.abs(quat.multiply(p, q) - quat.multiply(q, p)).max() > 1e-3


def test_conjugate_is_the_inverse_of_a_unit_quaternion(rng):
    q = quat.random_unit(20, rng)
    np.testing.assert_allclose(quat.multiply(q, quat.conjugate(q)),
                               np.tile([1.0, 0, 0, 0], (20, 1)), atol=1e-15)


def test_normalize_gives_unit_norm_and_keeps_direction(rng):
    q = rng.normal(size=(10, 4)) * rng.uniform(0.1, 10, (10, 1))
    n = quat.normalize(q)
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, rtol=1e-15)
    np.testing.assert_allclose(n * np.linalg.norm(q, axis=-1, keepdims=True), q, rtol=1e-14)


@pytest.mark.parametrize("scale", [1e-12, 1e-6, 0.5, 3.0, np.pi - 1e-6])
def test_from_rotvec_matches_scipy_at_every_angle(rng, scale):
    v = rng.normal(size=(30, 3))
    v *= scale / np.linalg.norm(v, axis=1, keepdims=True)
    ref = np.roll(Rotation.from_rotvec(v).as_quat(), 1, axis=-1)
    np.testing.assert_allclose(quat.from_rotvec(v), ref, atol=1e-15)


def test_from_rotvec_of_zero_is_the_identity():
    np.testing.assert_array_equal(quat.from_rotvec(np.zeros((2, 3))), [[1, 0, 0, 0]] * 2)


@pytest.mark.parametrize("scale", [1e-9, 0.1, 2.0, 3.1])
def test_to_rotvec_inverts_from_rotvec_and_matches_scipy(rng, scale):
    v = rng.normal(size=(30, 3))
    v *= scale / np.linalg.norm(v, axis=1, keepdims=True)
    q = quat.from_rotvec(v)
    np.testing.assert_allclose(quat.to_rotvec(q), v, atol=1e-14)
    np.testing.assert_allclose(quat.to_rotvec(-q), v, atol=1e-14)  # the shorter way round
    np.testing.assert_allclose(quat.to_rotvec(q), _scipy(q).as_rotvec(), atol=1e-14)


def test_to_matrix_and_rotate_inverse_match_scipy(rng):
    q = quat.random_unit(40, rng)
    R = _scipy(q).as_matrix()
    np.testing.assert_allclose(quat.to_matrix(q), R, atol=1e-15)
    v = rng.normal(size=(40, 3))
    np.testing.assert_allclose(quat.rotate_inverse(q, v), np.einsum("kji,kj->ki", R, v),
                               atol=1e-14)
    np.testing.assert_allclose(quat.rotate_inverse(q, v), _scipy(q).inv().apply(v), atol=1e-14)


def test_random_unit_is_unit_and_covers_both_hemispheres(rng):
    q = quat.random_unit(2000, rng)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, rtol=1e-15)
    # uniform rotations: every component has mean 0 and variance 1/4
    np.testing.assert_allclose(q.mean(axis=0), 0.0, atol=0.05)
    np.testing.assert_allclose((q * q).mean(axis=0), 0.25, atol=0.03)
