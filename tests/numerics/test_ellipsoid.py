"""The ellipsoid fits of imucal.numerics.ellipsoid: any unit, any centre, no guess."""

import numpy as np
import pytest

from imucal.numerics.ellipsoid import (
    algebraic_fit,
    fit_ellipsoid,
    is_ellipsoid,
    sphere_coverage,
    sym_from_vec,
)


def _points(n: int, G: np.ndarray, c: np.ndarray, rng: np.random.Generator,
            noise: float = 0.0) -> np.ndarray:
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    x = np.linalg.solve(G, u.T).T + c
    return x + rng.normal(0, noise, x.shape)


@pytest.mark.parametrize("scale, centre", [(1.0 / 4000, 32768.0), (1.0 / 5e-5, 1e-5),
                                           (2.0, 0.1)])
def test_the_closed_form_fit_recovers_a_noise_free_ellipsoid_in_any_unit(scale, centre):
    rng = np.random.default_rng(1)
    G = sym_from_vec(np.array([1.1, 0.05, -0.03, 0.9, 0.02, 1.0])) * scale
    c = centre * np.array([1.0, -0.5, 0.8])
    x = _points(300, G, c, rng)
    G1, c1, how = algebraic_fit(x)
    assert how == "ellipsoid"
    np.testing.assert_allclose(G1, G, rtol=1e-8)
    np.testing.assert_allclose(c1, c, rtol=1e-8, atol=1e-12 * abs(centre))


def test_the_likelihood_fit_and_its_standard_errors_are_honest():
    """Over 30 noisy draws, the errors of G and c divided by their standard errors have an
    RMS near 1 (not 0.3, not 3)."""
    G = sym_from_vec(np.array([2.0, 0.1, 0.0, 1.8, -0.1, 2.1]))
    c = np.array([0.1, -0.2, 0.05])
    z = []
    for seed in range(30):
        x = _points(400, G, c, np.random.default_rng(seed), noise=0.005)
        fit = fit_ellipsoid(x)
        z.append((fit.params - np.r_[G[0], G[1, 1:], G[2, 2], c]) / np.sqrt(np.diag(fit.cov)))
    rms = np.sqrt(np.mean(np.square(z), axis=0))
    assert np.all((rms > 0.6) & (rms < 1.4)), rms


def test_a_plane_of_points_is_no_ellipsoid_and_coverage_is_measured():
    assert not is_ellipsoid(np.diag([1.0, 1.0, -1.0]))
    assert is_ellipsoid(np.eye(3))
    rng = np.random.default_rng(0)
    u = rng.normal(size=(2000, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    covered, missing = sphere_coverage(u, 15.0)
    assert covered == 1.0 and len(missing) == 0
    upper = u[u[:, 2] > 0]
    covered, missing = sphere_coverage(upper, 15.0)
    assert 0.55 < covered < 0.7  # the upper half and a 15-degree rim below it
    assert np.all(missing[:, 2] < 0)


def test_the_sphere_fit_recovers_centre_and_radius_with_its_bias_removed():
    """Points on a cap of about 50 degrees around -z with noise of 0.7 % of the radius: the
    plain geometric fit's centre is off by 0.13 along z (2.5 standard errors) on average;
    with the bias measured and removed, by 0.04, and the errors over 12 draws are 0.9-1.7
    standard errors RMS (z the worst: what is left of the bias)."""
    from imucal.numerics.ellipsoid import sphere_fit

    c, r = np.array([6.0, -3.0, 1.0]), 43.0
    err, z = [], []
    for seed in range(12):
        rng = np.random.default_rng(seed)
        u = rng.normal(size=(3000, 3)) * [0.5, 0.5, 0.0] + [0.0, 0.0, -1.0]
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        fit = sphere_fit(c + r * u + rng.normal(0, 0.3, (3000, 3)))
        assert fit.model == "sphere" and np.allclose(fit.G, np.eye(3) * fit.G[0, 0])
        std = np.sqrt(np.diag(fit.cov))
        err.append(fit.c - c)
        z.append(np.r_[(1 / fit.G[0, 0] - r) / (std[0] * r * r), (fit.c - c) / std[6:9]])
    assert abs(np.mean(err, axis=0)[2]) < 0.06
    rms = np.sqrt(np.mean(np.square(z), axis=0))
    assert np.all((rms > 0.6) & (rms < 2.0)), rms
