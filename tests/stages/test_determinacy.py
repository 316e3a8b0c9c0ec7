"""What the data do not determine is said, not reported as certain (issue 27, item 2).

A coplanar session (every turn about the body's x axis: every pose's gravity in the y-z plane)
leaves the accelerometer's x scale and bias, and the gyroscope's y and z scales, to the prior.
The regularised fit's own covariance counted the prior as a measurement: s_x = 1.000 +- 5e-6
against a truth of 0.96, the held-out figures 0.2 mg, the verdict "usable with caveats".
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import imucal
from imucal.io.calibration_file import result_to_dict
from imucal.models import ACC_PARAM_NAMES, acc_theta, gyro_theta
from imucal.numerics.determinacy import determinacy
from imucal.stages import verdict as V
from imucal.synth import make_session


@pytest.fixture(scope="module")
def coplanar():
    session, truth = make_session(poses=30, seed=0, coplanar=True)
    return imucal.calibrate(session), truth


def test_the_synthetic_coplanar_session_is_coplanar(coplanar):
    r, truth = coplanar
    u = truth.acc.apply(r.detection.means)
    assert np.max(np.abs(u[:, 0])) < 0.02  # gravity along body x: none
    assert np.ptp(np.degrees(np.arctan2(u[:, 1], u[:, 2]))) > 180  # spread over the plane


def test_unmeasured_parameters_have_no_standard_error(coplanar):
    r, truth = coplanar
    acc = r.segments[0].acc
    assert {"s_x", "b_x"} <= set(acc.undetermined)
    und = np.isin(ACC_PARAM_NAMES, acc.undetermined)
    assert np.all(np.isnan(acc.std[und])) and np.all(np.isfinite(acc.std[~und]))
    # What is given a finite error is within it: |error / std| < 4 for each.
    z = (acc.params - acc_theta(truth.acc)) / acc.std
    assert np.all(np.abs(z[~und]) < 4), z
    # The x scale is several percent off: had it a finite error, it would be thousands of them.
    assert abs(acc.params[3] - acc_theta(truth.acc)[3]) > 0.02
    gyro = r.segments[0].gyro
    assert {"s_y", "s_z"} <= set(gyro.undetermined)
    names = list(gyro.param_names)
    for n in ("s_y", "s_z"):
        assert np.isnan(gyro.std[names.index(n)])
    i = names.index("s_x")  # every turn is about x: its scale is measured, and within its error
    err = gyro_theta(gyro.model)[i] - gyro_theta(truth.gyro)[i]
    assert np.isfinite(gyro.std[i]) and abs(err) < 4 * gyro.std[i]
    codes = [w.code for w in r.warnings]
    assert "acc_undetermined" in codes and "gyro_undetermined" in codes


def test_the_verdict_is_not_usable_and_names_them(coplanar):
    r, _ = coplanar
    v = r.verdict
    # The held-out figures look fine: they cannot see a direction no pose measured.
    assert r.segments[0].acc_cv.rms_mg < V.ACC_CAVEAT_MG
    assert v.level == V.NOT_USABLE and v.code == "acc_undetermined", v
    assert "s_x" in v.reason and "b_x" in v.reason and "not measured" in v.reason
    gyro = [c for c in v.caveats if c.code == "gyro_undetermined"]
    assert gyro and gyro[0].level == V.NOT_USABLE and "s_y" in gyro[0].reason
    d = json.loads(json.dumps(result_to_dict(r)))
    std = d["segments"][0]["accelerometer"]["std"]
    assert std["s_x"] is None and std["b_x"] is None and std["a_zx"] is not None
    assert d["segments"][0]["gyroscope"]["std"]["s_y"] is None


def test_a_well_posed_session_has_every_error_from_its_data():
    r = imucal.calibrate(make_session(poses=30, seed=21)[0])
    seg = r.segments[0]
    assert seg.acc.undetermined == () and seg.gyro.undetermined == ()
    assert np.all(np.isfinite(seg.acc.std)) and np.all(np.isfinite(seg.gyro.std))
    assert r.verdict.level == V.GOOD


def test_determinacy_is_the_unregularised_covariance():
    rng = np.random.default_rng(3)
    J = rng.normal(size=(40, 3))
    s2 = 0.25
    d = determinacy(J, s2, ("a", "b", "c"), 1.0)
    assert d.undetermined == ()
    np.testing.assert_allclose(d.std, np.sqrt(np.diag(s2 * np.linalg.inv(J.T @ J))), rtol=1e-9)
    # A parameter the data do not see at all (and one tied to it): no finite error, whatever
    # a prior would have made of them; the third is still measured.
    J2 = np.column_stack([J[:, 0], np.zeros(40), J[:, 2]])
    d2 = determinacy(J2, s2, ("a", "b", "c"), 1.0)
    assert d2.undetermined == ("b",) and np.isnan(d2.std[1])
    assert np.all(np.isfinite(d2.std[[0, 2]]))
    J3 = np.column_stack([J[:, 0], J[:, 0] * 2, J[:, 2]])  # only a + 2b is measured
    assert determinacy(J3, s2, ("a", "b", "c"), 1.0).undetermined == ("a", "b")
    # No data at all (every turn left out of a gyroscope fit): nothing is determined.
    assert determinacy(np.zeros((0, 3)), s2, ("a", "b", "c"), 1.0).undetermined == ("a", "b",
                                                                                     "c")
    # The limit decides: the same data, a limit below the errors, everything undetermined.
    assert determinacy(J, s2, ("a", "b", "c"), 1e-6).undetermined == ("a", "b", "c")
