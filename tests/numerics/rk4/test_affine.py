"""imucal.numerics.rk4.affine: ``M (w - b)`` for several models against einsum."""

import numpy as np
import pytest

from imucal.numerics.rk4.affine import calibrator


@pytest.mark.parametrize("shared_bias", [True, False])
def test_calibrator_applies_every_model(shared_bias):
    rng = np.random.default_rng(int(shared_bias))
    k, rows, K = 3, 11, 4
    Ms = np.eye(3) + 0.1 * rng.normal(size=(k, 3, 3))
    bs = np.tile(rng.normal(size=3), (k, 1)) if shared_bias else rng.normal(size=(k, 3))
    w = rng.normal(size=(3, rows, 1, K))
    got = np.stack(calibrator(list(zip(Ms, bs)))(tuple(w)))  # (3, rows, k, K)
    ref = np.einsum("mij,jrmk->irmk", Ms, w - bs.T[:, None, :, None])
    assert got.shape == (3, rows, k, K)
    np.testing.assert_allclose(got, ref, atol=1e-14)


def test_a_model_among_several_is_computed_as_alone():
    rng = np.random.default_rng(2)
    models = [(np.eye(3) + 0.1 * rng.normal(size=(3, 3)), rng.normal(size=3)) for _ in range(3)]
    w = tuple(rng.normal(size=(3, 8, 1, 5)))
    together = np.stack(calibrator(models)(w))
    for i, m in enumerate(models):
        np.testing.assert_array_equal(together[:, :, i], np.stack(calibrator([m])(w))[:, :, 0])
