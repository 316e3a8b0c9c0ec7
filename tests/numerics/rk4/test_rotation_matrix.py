"""imucal.numerics.rk4.rotation_matrix against scipy's Rotation, for quaternions of any norm."""

import numpy as np
from scipy.spatial.transform import Rotation

from imucal.numerics.rk4.rotation_matrix import matrix_rows


def test_matrix_rows_are_the_rotation_of_the_normalised_quaternion():
    rng = np.random.default_rng(0)
    rows, K = 6, 5
    q = rng.normal(size=(rows, K, 4)) * rng.uniform(0.5, 2.0, (rows, K, 1))
    out = np.empty((rows, 9, K))
    assert matrix_rows(tuple(np.moveaxis(q, -1, 0)), out) is out
    ref = Rotation.from_quat(np.roll(q.reshape(-1, 4), -1, -1)).as_matrix().reshape(rows, K, 9)
    np.testing.assert_allclose(np.moveaxis(out, 1, 2), ref, atol=1e-14)


def test_matrix_rows_write_into_a_strided_view_and_leave_the_quaternions_alone():
    rng = np.random.default_rng(1)
    q = rng.normal(size=(4, 3, 7))
    keep = q.copy()
    R = np.empty((7, 9, 3))  # the variational scan writes through a transposed view like this
    matrix_rows(tuple(q), R.transpose(2, 1, 0))
    np.testing.assert_array_equal(q, keep)
    ref = Rotation.from_quat(np.roll(np.moveaxis(q, 0, -1).reshape(-1, 4), -1, -1)).as_matrix()
    np.testing.assert_allclose(R.transpose(2, 0, 1).reshape(-1, 9), ref.reshape(-1, 9),
                               atol=1e-14)
