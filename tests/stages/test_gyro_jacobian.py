"""The gyroscope fit's Jacobian (variational equation of M5) against central differences."""

import numpy as np
import pytest

from imucal.models import GYRO_THETA0
from imucal.numerics import quaternion as quat
from imucal.stages.gyro_transitions import Transitions, gyro_model_of
from imucal.synth import make_session


def _central(res, theta, h=1e-6):
    cols = []
    for i in range(len(theta)):
        e = np.zeros(len(theta))
        e[i] = h * max(1.0, abs(theta[i]))
        cols.append((res(theta + e) - res(theta - e)) / (2 * e[i]))
    return np.column_stack(cols)


@pytest.mark.parametrize("rate, n_bias", [(100.0, 0), (100.0, 3), (400.0, 0)])
def test_jacobian_matches_central_differences(rate, n_bias):
    session, truth = make_session(poses=14, seed=3, gyro_rate=rate)
    blocks = truth.pose_times
    assert len(blocks) == 14
    tr = Transitions(session.gyro, session.t_gyro, blocks)
    rng = np.random.default_rng(0)
    u = quat.normalize(rng.normal(size=(len(blocks), 3)))
    u_prev, u_meas = u[:-1], u[1:]
    bias, s0 = rng.normal(0, 0.01, 3), 1.0
    theta = np.r_[GYRO_THETA0 + rng.normal(0, 0.02, 9), rng.normal(0, 0.01, n_bias)]

    def model_of(th):
        return gyro_model_of(th, bias, s0)

    def res(th):
        return (u_meas - tr.predict(model_of(th), u_prev)).ravel()

    J = tr.jacobian(model_of, theta, u_prev)
    ref = _central(res, theta)
    assert J.shape == ref.shape == (3 * len(u_prev), 9 + n_bias)
    # Trapezoidal quadrature of the variational equation: relative error ~ (w h)^2 / 12.
    rel = np.linalg.norm(J - ref, axis=0) / np.linalg.norm(ref, axis=0)
    assert rel.max() < (1e-4 if rate == 100.0 else 1e-5), rel
    # ... and not by accident: a wrong sign or a transposed matrix is off by order one.
    assert np.linalg.norm(ref, axis=0).min() > 1e-3
