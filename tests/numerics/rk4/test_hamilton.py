"""imucal.numerics.rk4.hamilton: both forms of the product against scipy's Rotation."""

import numpy as np
from scipy.spatial.transform import Rotation

from imucal.numerics.rk4.hamilton import mul, mul_stacked


def _scipy_product(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """p (x) q for (N, 4) scalar-first quaternions of any norm, by scipy on the unit ones."""
    r = Rotation.from_quat(np.roll(p, -1, -1)) * Rotation.from_quat(np.roll(q, -1, -1))
    out = np.roll(r.as_quat(canonical=False), 1, -1)
    return out * (np.linalg.norm(p, axis=-1) * np.linalg.norm(q, axis=-1))[:, None]


def test_mul_of_component_arrays_is_the_hamilton_product():
    rng = np.random.default_rng(0)
    p, q = rng.normal(size=(100, 4)), rng.normal(size=(100, 4))
    got = np.stack(mul(tuple(p.T), tuple(q.T)), axis=-1)
    ref = _scipy_product(p, q)
    # scipy may return -r: the sign of a rotation's quaternion is free
    np.testing.assert_allclose(got * np.sign(got[:, :1] * ref[:, :1]), ref, atol=1e-13)


def test_mul_stacked_equals_mul_on_any_shape():
    rng = np.random.default_rng(1)
    p, q = rng.normal(size=(4, 7, 3)), rng.normal(size=(4, 7, 3))
    np.testing.assert_allclose(mul_stacked(p, q), np.stack(mul(tuple(p), tuple(q))), atol=1e-14)


def test_order_matters_and_identity_is_neutral():
    rng = np.random.default_rng(2)
    p, q = tuple(rng.normal(size=(4, 5))), tuple(rng.normal(size=(4, 5)))
    assert np.abs(np.stack(mul(p, q)) - np.stack(mul(q, p))).max() > 1e-3
    one = (np.ones(5), np.zeros(5), np.zeros(5), np.zeros(5))
    np.testing.assert_array_equal(np.stack(mul(one, p)), np.stack(p))
    np.testing.assert_array_equal(np.stack(mul(p, one)), np.stack(p))


def test_mul_leaves_its_inputs_alone():
    rng = np.random.default_rng(3)
    p = tuple(rng.normal(size=(4, 6)))
    keep = np.stack(p).copy()
    mul(p, p)
    np.testing.assert_array_equal(np.stack(p), keep)
