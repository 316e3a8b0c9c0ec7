"""The straightforward RK4 loop the vectorised scans are checked against."""

import numpy as np
import pytest

from imucal.numerics import quaternion as quat


def sequential_rk4(w: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Orientation (len(t), 4) at every sample from q = identity: the four RK4 stages of
    ``dq/dt = 1/2 q (x) (0, w)`` written out one step at a time (half-step rate: the mean of the
    two samples, method.md M5), normalised after every step."""
    q = np.array([1.0, 0.0, 0.0, 0.0])
    out = [q]

    def f(q, w):
        return 0.5 * quat.multiply(q, np.r_[0.0, w])

    for i in range(len(t) - 1):
        h = t[i + 1] - t[i]
        wm = 0.5 * (w[i] + w[i + 1])
        k1 = f(q, w[i])
        k2 = f(q + h / 2 * k1, wm)
        k3 = f(q + h / 2 * k2, wm)
        k4 = f(q + h * k3, w[i + 1])
        q = q + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        q = q / np.linalg.norm(q)
        out.append(q)
    return np.array(out)


@pytest.fixture
def sequential():
    return sequential_rk4


def same_rotation(q: np.ndarray, ref: np.ndarray, atol: float) -> None:
    """q and -q are the same rotation."""
    np.testing.assert_allclose(q * np.sign(q[..., :1]), ref * np.sign(ref[..., :1]), atol=atol)


@pytest.fixture
def assert_same_rotation():
    return same_rotation
