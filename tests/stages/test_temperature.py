"""Temperature (method.md §12): each sensor's bias a polynomial in temperature (M16, M17), its
order chosen by cross-validation, never extrapolated; on synthetic ramps with their truth."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from imucal.io.calibration_file import result_to_dict
from imucal.pipeline import calibrate, calibrate_temperature
from imucal.report import report
from imucal.synth import TemperatureProfile, make_session

FLAT = TemperatureProfile(acc=(), gyro=())
LINEAR = TemperatureProfile(acc=((4e-4, -3e-4, 2e-4),), gyro=((1e-4, -8e-5, 6e-5),))
QUADRATIC = TemperatureProfile()  # 15 to 45 deg C, 0.4 mg/degC and 0.01 mg/degC^2 or so
CUBIC = TemperatureProfile(acc=((4e-4, -3e-4, 2e-4), (1e-5, 1.5e-5, -1e-5), (1e-6, -1e-6, 8e-7)),
                           gyro=((1e-4, -8e-5, 6e-5), (3e-6, -2e-6, 4e-6), (4e-7, 3e-7, -3e-7)))


def _fit(seed: int, profile: TemperatureProfile, poses: int = 30, **settings):
    session, truth = make_session(poses=poses, seed=seed, acc_rate=200.0, temperature=profile)
    result = calibrate_temperature(calibrate(session, **settings))
    return result, truth


def _residuals(result, truth) -> tuple[float, float]:
    """RMS bias error over temperatures the fit never saw (a fine grid across its span): mg
    and deg/s."""
    acc, gyro = result.temperature
    grid = np.linspace(acc.span[0], acc.span[1], 301)
    acc_mg = (acc.bias_at(grid) - truth.acc_bias_at(grid)) * truth.acc.K * 1e3
    gyro_dps = np.degrees(gyro.bias_at(grid) - truth.gyro_bias_at(grid))
    return float(np.sqrt(np.mean(acc_mg**2))), float(np.sqrt(np.mean(gyro_dps**2)))


@pytest.mark.parametrize(("profile", "order"), [(LINEAR, 1), (QUADRATIC, 2), (CUBIC, 3)])
def test_a_15_to_45_degC_ramp_gives_the_bias_within_1_mg_and_0_02_dps(profile, order):
    orders = []
    for seed in range(4):
        result, truth = _fit(seed, profile, single_segment=True)
        acc, gyro = result.temperature
        assert acc.span[0] < 16 and acc.span[1] > 44
        # The data points: every still pose's temperature, on the ramp.
        assert len(acc.temps) == len(result.detection.blocks) == len(gyro.residuals)
        assert (acc.temps.min(), acc.temps.max()) == acc.span
        acc_mg, gyro_dps = _residuals(result, truth)
        assert acc_mg <= 1.0 and gyro_dps <= 0.02, (seed, acc_mg, gyro_dps)
        orders.append((acc.order, gyro.order))
        # The constant model leaves several mg: the polynomial is what brings it under 1.
        flat = np.ptp(truth.acc_bias_at(np.array([15.0, 45.0])) * 1e3, axis=0).max()
        assert flat > 5.0
    assert sum(a == order for a, _ in orders) >= 3 and sum(g == order for _, g in orders) >= 3


@pytest.mark.parametrize(("profile", "order"), [(FLAT, 0), (LINEAR, 1), (QUADRATIC, 2)])
def test_20_poses_choose_the_truths_order_and_say_what_they_cannot_try(profile, order):
    """From 20 poses M17's 9 + 3p unknowns leave five folds too few blocks for order 2 (order 1
    was chosen for a quadratic drift, about 2 mg left): leave-one-out gives the truth's order
    and the bias within 1 mg and 0.02 deg/s; order 3 (18 unknowns from 20 norms) is not tried,
    and said."""
    orders = []
    for seed in range(1, 4):
        result, truth = _fit(seed, profile, poses=20, single_segment=True)
        acc, gyro = result.temperature
        acc_mg, gyro_dps = _residuals(result, truth)
        assert acc_mg <= 1.0 and gyro_dps <= 0.02, (seed, acc_mg, gyro_dps)
        orders.append((acc.order, gyro.order))
        assert np.isfinite(acc.cv_rms[:3]).all() and np.isnan(acc.cv_rms[3])
        assert any(n.startswith(f"accelerometer: orders 3 and above not tried: {acc.blocks} "
                                "still blocks, and order 3 needs 21") for n in acc.notes)
    assert sum(a == order for a, _ in orders) >= 2 and sum(g == order for _, g in orders) >= 2


def test_a_5_degC_span_is_said_and_not_extrapolated():
    narrow = TemperatureProfile(start=28.0, end=33.0)
    result, _ = _fit(1, narrow, single_segment=True)
    acc, gyro = result.temperature
    assert acc.span_c == pytest.approx(5.0, abs=0.3)
    for fit in (acc, gyro):
        assert any("span only" in n and "not extrapolated" in n for n in fit.notes)
        edge = fit.bias_at(np.array([fit.span[1]]))
        np.testing.assert_array_equal(fit.bias_at(np.array([45.0, 80.0])), np.vstack([edge] * 2))
    said = [ln.text for ln in report(result).overview if ln.label == "temperature"]
    assert any("under the 10 deg C" in t for t in said)


def test_calib_json_holds_the_polynomials_only_when_fitted():
    result, truth = _fit(2, QUADRATIC, single_segment=True)
    d = json.loads(json.dumps(result_to_dict(result)))["temperature"]
    assert d["accelerometer"]["order"] == 2 and len(d["accelerometer"]["coefficients"]) == 3
    g = d["gyroscope"]
    # The gyroscope's linear coefficient is the truth's c_1 about the span's middle.
    t0 = g["reference_degC"]
    c1 = np.array(QUADRATIC.gyro[0]) + 2 * np.array(QUADRATIC.gyro[1]) * (t0 - QUADRATIC.ref)
    np.testing.assert_allclose(g["coefficients"][1], c1, atol=1e-5)
    plain, _ = make_session(poses=12, seed=1)
    assert "temperature" not in result_to_dict(calibrate_temperature(calibrate(plain)))


def test_a_run_split_by_the_drift_is_calibrated_again_as_one_segment():
    result, truth = _fit(0, QUADRATIC)  # the grouping splits this one where the bias moved
    assert len(result.segments) == 1
    assert "calibrated again as one segment" in result.temperature[0].notes[0]
    acc_mg, gyro_dps = _residuals(result, truth)
    assert acc_mg <= 1.0 and gyro_dps <= 0.02
    assert len(calibrate(make_session(poses=30, seed=0, acc_rate=200.0,
                                      temperature=QUADRATIC)[0]).segments) > 1


def test_two_imus_on_one_thermometer_each_get_their_own_order_and_still_agree():
    """The first IMU drifts (order 2), the second does not (order 0): each triad's own fit says
    so from the one temperature column, and the triads, compared at each pose's temperature,
    agree within 1 mg with the rotation within 0.05 deg and its 1-sigma honest."""
    from imucal.pipeline import calibrate_triads
    from imucal.stages.triads import angle_deg
    from imucal.synth import SecondTriad

    err, sd = [], []
    for seed in range(8):
        session, truth = make_session(poses=30, seed=seed, acc_rate=200.0,
                                      second_acc=SecondTriad(rate=400.0, gyro=True),
                                      temperature=QUADRATIC)
        result = calibrate_triads(calibrate_temperature(calibrate(session)), temperature=True)
        (tri,) = result.triads
        assert [(f.sensor, f.order) for f in result.temperature] == [
            ("accelerometer", 2), ("gyroscope", 2)]
        assert [f.order for f in tri.result.temperature] == [0, 0]
        a = tri.agreement
        assert a.held_out_rms_mg < 1.0
        err.append(angle_deg(a.rotation.R, truth.triads[0].R))
        sd.append(a.rotation.std_total_deg)
    assert max(err) < 0.05
    ratio = float(np.sqrt(np.mean(np.square(err))) / np.sqrt(np.mean(np.square(sd))))
    assert 1 / 1.5 < ratio < 1.5, (ratio, err, sd)


@pytest.mark.parametrize("step", [0.0, 2e-3])
def test_heating_and_cooling_legs_are_compared(step):
    """Up to 45 deg C and back over 40 poses (20 each way): a bias step while cooling (2 mg,
    0.5 mrad/s per axis) is found at its size and called hysteresis; without one, none is."""
    import re

    profile = TemperatureProfile(back=True, acc_hysteresis=(step, -step, step),
                                 gyro_hysteresis=(step / 4, step / 4, -step / 4))
    for seed in range(2):
        result, _ = _fit(seed, profile, poses=40)
        acc, gyro = result.temperature
        for fit, truth in ((acc, np.sqrt(3) * step * 1e3),
                           (gyro, np.degrees(np.sqrt(3) * step / 4))):
            said = fit.hysteresis
            size = float(re.search(r"differ by ([0-9.e-]+)", said).group(1))
            if step:
                assert said.endswith("hysteresis, which one polynomial in temperature cannot "
                                     "model")
                assert size == pytest.approx(truth, rel=0.15)
            else:
                assert said.endswith("no hysteresis beyond the noise")


def test_scales_that_change_with_temperature_are_found_and_constant_ones_are_not():
    """K(T) = K (1 + k (T - 30)) with k = (100, -50, 80) ppm per deg C: the slope is chosen by
    the cross-validation and measured within 30 ppm per deg C, the bias still within 1 mg; with
    constant scales no slope is fitted."""
    slope = np.array([1e-4, -5e-5, 8e-5])
    for seed in range(3):
        result, truth = _fit(seed, TemperatureProfile(acc_scale=tuple(slope)))
        acc = result.temperature[0]
        assert acc.scale_slope is not None
        np.testing.assert_allclose(acc.scale_slope, slope, atol=3e-5)
        assert any("ppm per deg C" in n for n in acc.notes)
        grid = np.linspace(*acc.span, 301)
        err = (acc.bias_at(grid) - truth.acc_bias_at(grid)) * 1e3
        assert np.sqrt(np.mean(err**2)) < 1.0
        flat, _ = _fit(seed, QUADRATIC)
        assert flat.temperature[0].scale_slope is None


def _device_sessions(seed: int, temps: tuple[float, ...], profile: TemperatureProfile):
    """Sessions of one device (the same M2 and M4), each at one temperature, other poses."""
    from imucal.synth import random_acc_model, random_gyro_model

    rng = np.random.default_rng(100 + seed)
    acc, gyro = random_acc_model(rng), random_gyro_model(rng)
    out = []
    for i, temp in enumerate(temps):
        out.append(make_session(poses=20, seed=10 * seed + i, acc_rate=200.0, acc_truth=acc,
                                gyro_truth=gyro, temperature=dataclasses.replace(
                                    profile, start=temp, end=temp)))
    return out


def test_sessions_of_one_device_at_five_temperatures():
    """--same-device: five sessions at 15-45 deg C, each at one temperature: the pooled still
    poses give the truth's order and the bias within 1 mg and 0.02 deg/s between them."""
    from imucal.pipeline import calibrate_same_device

    for seed in range(2):
        runs = _device_sessions(seed, (15.0, 22.0, 30.0, 37.0, 45.0), QUADRATIC)
        result = calibrate_same_device([calibrate(s) for s, _ in runs])
        truth = runs[0][1]
        acc, gyro = result.temperature
        assert (acc.order, gyro.order) == (2, 2)
        assert acc.span == pytest.approx((15.0, 45.0), abs=0.2)
        assert "from 5 sessions of one device" in acc.notes[0]
        acc_mg, gyro_dps = _residuals(result, truth)
        assert acc_mg <= 1.0 and gyro_dps <= 0.02


def test_same_device_without_a_temperature_is_one_line():
    from imucal.errors import ImucalError
    from imucal.pipeline import calibrate_same_device

    warm, _ = make_session(poses=12, seed=1, temperature=QUADRATIC)
    cold, _ = make_session(poses=12, seed=2)
    with pytest.raises(ImucalError, match="--same-device: the session holds no temperature"):
        calibrate_same_device([calibrate(warm), calibrate(cold)])
