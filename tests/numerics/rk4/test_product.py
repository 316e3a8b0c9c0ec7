"""imucal.numerics.rk4.product: the pairwise ordered product against scipy's composition, on
both of its paths (elementwise for large arrays, stacked matrix products for small ones)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from imucal.numerics import quaternion as quat
from imucal.numerics.rk4.product import SMALL, ordered_product, ordered_product_soa, product_rows


def _composed(P: np.ndarray) -> np.ndarray:
    """P[0] (x) P[1] (x) ... for (L, 4) unit quaternions, by scipy, scalar first."""
    r = Rotation.identity()
    for p in P:
        r = r * Rotation.from_quat(np.roll(p, -1))
    return np.roll(r.as_quat(canonical=False), 1)


def _check(got: np.ndarray, ref: np.ndarray, atol: float) -> None:
    np.testing.assert_allclose(got * np.sign(got[..., :1]), ref * np.sign(ref[..., :1]),
                               atol=atol)


@pytest.mark.parametrize("L, K", [(1, 3), (2, 3), (7, 5), (64, 4), (301, 10), (3001, 1)])
def test_product_rows_is_the_ordered_product(L, K):
    # L * K above SMALL goes through the elementwise levels first; odd L folds a last row in.
    rng = np.random.default_rng(L + K)
    P = quat.random_unit(L * K, rng).reshape(L, K, 4)
    got = np.stack(product_rows(tuple(np.moveaxis(P, -1, 0))), axis=-1)
    ref = np.array([_composed(P[:, k]) for k in range(K)])
    _check(got, ref, atol=1e-12 if L < 1000 else 1e-11)


def test_both_paths_are_exercised():
    assert 301 * 10 > SMALL > 64 * 4


def test_the_product_of_norms_is_kept_unnormalised():
    rng = np.random.default_rng(9)
    P = rng.normal(size=(4, 33, 2))
    got = np.stack(product_rows(tuple(P)))
    np.testing.assert_allclose(np.linalg.norm(got, axis=0),
                               np.prod(np.linalg.norm(P, axis=0), axis=0), rtol=1e-12)


def test_ordered_product_of_stacked_quaternions_is_normalised():
    rng = np.random.default_rng(10)
    P = quat.random_unit(2 * 3 * 20, rng).reshape(2, 3, 20, 4) * 1.001  # not quite unit
    got = ordered_product(P)
    assert got.shape == (2, 3, 4)
    np.testing.assert_allclose(np.linalg.norm(got, axis=-1), 1.0, rtol=1e-15)
    for i in range(2):
        for j in range(3):
            _check(got[i, j], _composed(P[i, j] / 1.001), atol=1e-13)
    np.testing.assert_array_equal(ordered_product_soa(tuple(np.moveaxis(P, -1, 0))), got)
