"""The gyroscope's integration and sign convention (method.md M5), on rotations of known axis."""

import numpy as np

from imucal.numerics import quaternion as quat
from imucal.numerics.rk4 import integrate_transitions
from imucal.numerics.rk4.step import rk4_step


def _sequential(w, t):
    """Plain per-step RK4 loop (the straightforward way) for comparison."""
    q = np.array([1.0, 0, 0, 0])

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
        q /= np.linalg.norm(q)
    return q


def test_rotation_of_known_axis_and_angle():
    # 90 degrees about body z in 2 s at 100 Hz, with a smooth rate profile.
    t = np.linspace(0.0, 2.0, 201)
    rate = (np.pi / 2) * (np.pi / 4) * np.sin(np.pi * t / 2)  # integrates to pi/2
    w = np.column_stack([np.zeros_like(t), np.zeros_like(t), rate])
    q = integrate_transitions(w, t, np.array([0]), np.array([200]))[0]
    R = quat.to_matrix(q)
    # The half-step rate is the mean of two samples (the thesis's choice), so the integration
    # is second order in the sample spacing: about 3e-5 rad here.
    # Body x after a +90 degree turn about z points along the starting frame's +y.
    np.testing.assert_allclose(R @ [1, 0, 0], [0, 1, 0], atol=1e-4)
    # Gravity seen in the body frame (M5): u_k = R^T u_(k-1). Start with gravity along the
    # starting frame's +y: after turning +90 degrees about z the body sees it along +x.
    np.testing.assert_allclose(quat.rotate_inverse(q, np.array([0.0, 1.0, 0.0])), [1, 0, 0],
                               atol=1e-4)
    assert abs(2 * np.degrees(np.arccos(q[0])) - 90.0) < 5e-3


def test_vectorised_product_equals_sequential_rk4():
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.005, 0.015, 300))
    w = rng.normal(0, 1.5, (300, 3))
    starts, ends = np.array([0, 50, 120]), np.array([299, 90, 121])
    got = integrate_transitions(w, t, starts, ends)
    for q, s, e in zip(got, starts, ends):
        ref = _sequential(w[s:e + 1], t[s:e + 1])
        np.testing.assert_allclose(q * np.sign(q[0]), ref * np.sign(ref[0]), atol=1e-12)


def test_rk4_step_is_fourth_order():
    # Constant rate: the exact step is exp(w h / 2); the error of one RK4 step is O(h^5).
    w = np.array([[0.3, -1.2, 2.0]])
    errs = []
    for h in (0.1, 0.05):
        P = np.array(rk4_step(*w[0], *w[0], h))
        P /= np.linalg.norm(P)
        exact = quat.from_rotvec(w[0] * h)
        errs.append(np.abs(P - exact).max())
    assert errs[0] / errs[1] > 20  # 2^5 = 32 for a fifth-order local error
