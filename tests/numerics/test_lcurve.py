"""imucal.numerics.lcurve against an L-curve whose curvature is known in closed form.

With ``s = log lambda - s0``, ``log rho = log(1 + e^s)`` and ``log eta = log(1 + e^-s)`` draw an
L whose corner is at ``s = 0`` by symmetry, with signed curvature
``kappa(s) = sig (1 - sig) / (sig^2 + (1 - sig)^2)^(3/2)``, ``sig = 1 / (1 + e^-s)``.
"""

import numpy as np
import pytest

from imucal.numerics.lcurve import lcurve_corner


def _curve(s0: float, n: int = 81, span: float = 8.0):
    t = np.linspace(-span, span, n) + s0
    s = t - s0
    rho = np.exp(np.logaddexp(0.0, s))
    eta = np.exp(np.logaddexp(0.0, -s))
    sig = 1.0 / (1.0 + np.exp(-s))
    kappa = sig * (1 - sig) / (sig**2 + (1 - sig) ** 2) ** 1.5
    return np.exp(t), rho, eta, kappa


@pytest.mark.parametrize("s0", [-3.0, 0.0, 2.2])
def test_corner_is_the_point_of_maximum_curvature(s0):
    lambdas, rho, eta, _ = _curve(s0)
    i, _ = lcurve_corner(lambdas, rho, eta)
    assert abs(np.log(lambdas[i]) - s0) <= 0.5 * (np.log(lambdas[1]) - np.log(lambdas[0])) + 1e-12


def test_curvature_is_the_closed_form():
    lambdas, rho, eta, kappa = _curve(1.0, n=401)
    _, curv = lcurve_corner(lambdas, rho, eta)
    # central differences of central differences: O(h^2) with h = 0.04
    np.testing.assert_allclose(curv[2:-2], kappa[2:-2], atol=2e-3)
    assert curv[0] == 0.0 and curv[-1] == 0.0  # one-sided ends are not trusted


def test_corner_does_not_depend_on_the_order_of_magnitude_of_rho_and_eta():
    lambdas, rho, eta, _ = _curve(0.7)
    i, _ = lcurve_corner(lambdas, rho, eta)
    j, _ = lcurve_corner(lambdas, 1e-6 * rho, 1e4 * eta)
    assert i == j


def test_a_curve_that_turns_the_other_way_has_no_corner():
    # rho falls and eta rises: the curve turns clockwise, no L; the smallest lambda is taken.
    lambdas, rho, eta, _ = _curve(0.0)
    i, curv = lcurve_corner(lambdas, eta, rho)
    assert i == 0 and np.all(curv <= 1e-12)


def test_a_flat_curve_has_no_corner():
    # log(logspace) is uniform only to rounding: the gradients of a constant are ~1e-16, not 0
    lambdas = np.logspace(-6, 2, 20)
    i, curv = lcurve_corner(lambdas, np.full(20, 3.0), np.full(20, 0.5))
    assert i == 0 and np.all(curv == 0.0)


def test_fewer_than_three_points_take_the_smallest_lambda():
    i, curv = lcurve_corner(np.array([1e-2, 1e-4]), np.array([1.0, 2.0]), np.array([2.0, 1.0]))
    assert i == 1 and curv.tolist() == [0.0, 0.0]
