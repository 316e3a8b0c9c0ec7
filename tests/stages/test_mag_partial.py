"""M8r: the magnetometer's shape held towards a sphere by a Tikhonov term, lambda at the
L-curve's corner (docs/method.md §9), against the truth of synthetic sessions whose field
reached part of the sphere of directions, and the curve in calib.json."""

from __future__ import annotations

import json

import numpy as np
import pytest

import imucal
from imucal.io.calibration_file import result_to_dict
from imucal.numerics.ellipsoid import fit_ellipsoid, sphere_fit
from imucal.numerics.ellipsoid_tikhonov import LAMBDAS, choose_corner, regularised_fit
from imucal.stages.mag import calibrate_magnetometer
from imucal.synth import make_session


def _session(seed: int, poses: int):
    return make_session(seed=seed, poses=poses, still=2.0, move=1.5, init_still=2.0,
                        acc_rate=50.0, mag_rate=25.0)


def _soft_error(G: np.ndarray, M_true: np.ndarray) -> float:
    return float(np.abs(G / np.linalg.det(G) ** (1 / 3) - M_true).max())


def _held_out(x: np.ndarray, make) -> float:
    cut = len(x) // 2
    r = np.r_[make(x[cut:]).residuals(x[:cut]), make(x[:cut]).residuals(x[cut:])]
    return float(100 * np.sqrt(np.mean(r * r)))


def test_partial_coverage_the_regularised_soft_iron_is_nearer_the_truth():
    """Five poses (16-36 % of the field's directions), seeds 0-5 (bench/mag_partial.md):
    the plain ellipsoid escapes on seed 3 (soft iron 0.35 off, hard iron 1.4 fields), the
    regularised fit does not; seed by seed it is within 1.5x of the plain fit's error (seed 1:
    0.0083 against 0.0064) and over the seeds far nearer. Held out (each half of the time
    judged by the other half's fit of the same kind) it is no worse than the sphere's in the
    median, and at most 10 % worse on any seed (seed 3: 0.95 against 0.87 %)."""
    reg, plain, held_reg, held_sphere = [], [], [], []
    for seed in range(6):
        s, truth = _session(seed, 5)
        x = np.asarray(s.others[0].values, float)
        M = truth.mag.M
        reg.append(_soft_error(regularised_fit(x).fit.G, M))
        G = fit_ellipsoid(x).G
        plain.append(_soft_error(G, M) if np.linalg.det(G) > 0 else np.inf)
        held_reg.append(_held_out(x, lambda y: regularised_fit(y).fit))
        held_sphere.append(_held_out(x, sphere_fit))
    reg, plain = np.array(reg), np.array(plain)
    assert np.all(reg < 1.5 * plain) and np.all(reg < 0.05), (reg, plain)
    assert np.sqrt(np.mean(reg ** 2)) < 0.2 * np.sqrt(np.mean(plain ** 2))
    held_reg, held_sphere = np.array(held_reg), np.array(held_sphere)
    assert np.median(held_reg) <= np.median(held_sphere), (held_reg, held_sphere)
    assert np.all(held_reg <= 1.1 * held_sphere), (held_reg, held_sphere)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_full_coverage_lands_on_the_plain_fit(seed):
    """Sixteen poses (66-74 % of the directions): no corner past the curve's start, lambda is
    the grid's smallest (the plain fit), and M, b, F are the plain relative-residual
    ellipsoid's (the fit before M8r) within 0.4 of their standard errors: measured 0.07-0.34,
    from the residual in the raw unit, which halves the field's noise bias (over 12 seeds
    the field 8e-5 above the truth against 2.4e-4, M and b 13-21 % nearer the truth RMS)."""
    s, _ = _session(seed, 16)
    stream = s.others[0]
    fit = calibrate_magnetometer(stream)
    assert fit.lcurve.well_posed and fit.lam == fit.lcurve.lambdas[0] == 1e-10
    assert fit.soft_iron and not fit.undetermined
    plain = fit_ellipsoid(np.asarray(stream.values, float))
    F = np.linalg.det(plain.G) ** (-1 / 3)
    assert np.all(np.abs(F * plain.G - fit.M) < 0.4 * fit.std_M)
    assert np.all(np.abs(plain.c - fit.b) < 0.4 * fit.std_b)
    assert abs(F - fit.field) < 0.4 * fit.std_field


def test_corner_past_the_start_and_no_corner_on_a_straight_fall():
    """choose_corner: a curve that stands still, then falls in eta at constant rho and turns
    to rho rising (an L) has its corner at the turn; one that falls straight (no bend) has
    none, and its corner is the sphere's end when it never reaches the plain fit."""
    lam = LAMBDAS
    t = np.log(lam)
    # an L: eta falls from 1 to 0.05 around lambda 1e-6, rho rises from 1e-2 around 1e-2
    eta = (0.05 + 0.95 / (1 + np.exp(2 * (t - np.log(1e-6))))) / (
        1 + np.exp(2 * (t - np.log(1e-1))))
    rho = 1e-2 * (1 + 5 / (1 + np.exp(-2 * (t - np.log(1e-2)))))
    c, _, until = choose_corner(lam, rho, eta)
    assert 1e-5 < lam[c] < 1e-2 and until >= 1
    straight = np.linspace(0.12, 1e-5, len(lam))
    c, _, until = choose_corner(lam, np.full(len(lam), 0.1) * (1 + 1e-4 * np.arange(len(lam))),
                                straight)
    assert until == 0 and c == len(lam) - 1


def test_the_curve_is_in_calib_json():
    """The magnetometer's section holds the L-curve (lambdas, rho, eta, the corner) and the
    lambda chosen, read back from the JSON text."""
    s, _ = make_session(poses=14, seed=4, still=2.0, move=1.5, acc_rate=50.0, mag_rate=25.0)
    r = imucal.calibrate(s)
    fit = r.magnetometer
    sec = json.loads(json.dumps(result_to_dict(r)))["magnetometer"]
    lc = sec["lcurve"]
    np.testing.assert_array_equal(lc["lambdas"], fit.lcurve.lambdas)
    np.testing.assert_array_equal(lc["residual_norm"], fit.lcurve.residual_norm)
    np.testing.assert_array_equal(lc["solution_norm"], fit.lcurve.solution_norm)
    assert lc["corner"] == fit.lcurve.corner and sec["lambda"] == fit.lam
    assert lc["lambdas"][lc["corner"]] == sec["lambda"]
    assert lc["well_posed"] is fit.lcurve.well_posed
    assert sec["undetermined"] == list(fit.undetermined)
    # rho is the RMS norm residual in the raw unit: the noise, 0.002 gauss
    assert 0.0015 < lc["residual_norm"][lc["corner"]] < 0.0025
