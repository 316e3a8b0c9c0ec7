"""Several triads in one device (method.md §11): the rotation of a second accelerometer to the
reference from the shared still blocks (M12, M13), its standard error, and the agreement after
calibration, on synthetic sessions with their truth."""

from __future__ import annotations

import json

import numpy as np
import pytest

from imucal.errors import ImucalError
from imucal.io.calibration_file import result_to_dict
from imucal.pipeline import calibrate, calibrate_triads
from imucal.report import report
from imucal.stages.triads import angle_deg, fit_rotation, kabsch
from imucal.synth import SecondTriad, make_session

SEEDS = range(12)


def _run(seed: int, **spec):
    session, truth = make_session(poses=20, seed=seed, acc_rate=200.0,
                                  second_acc=SecondTriad(rate=400.0, **spec))
    return calibrate_triads(calibrate(session)), truth


@pytest.fixture(scope="module")
def runs():
    """12 sessions of two IMUs (the second's accelerometer at 400 Hz on its own clock, 8 g
    range, twice the noise, with a gyroscope of its own; both turned 3 deg from the first)."""
    return [_run(seed, gyro=True) for seed in SEEDS]


def test_rotation_to_the_reference_within_0_05_deg_of_the_truth_from_20_poses(runs):
    errors = []
    for result, truth in runs:
        (tri,) = result.triads
        assert tri.result is not None and tri.agreement is not None
        a = tri.agreement
        assert a.blocks == 20  # every reference pose seen by the 400 Hz triad
        errors.append(angle_deg(a.rotation.R, truth.triads[0].R))
        # The rotation drawn is 3 deg: the estimate is that, not the identity.
        assert a.angle_deg == pytest.approx(3.0, abs=0.05)
    assert max(errors) < 0.05, errors


def test_the_reported_standard_error_is_honest_over_seeds(runs):
    """The error's size over seeds against sqrt(trace cov): within 1.5x either way."""
    err = np.array([angle_deg(r.triads[0].agreement.rotation.R, t.triads[0].R)
                    for r, t in runs])
    sd = np.array([r.triads[0].agreement.rotation.std_total_deg for r, _ in runs])
    ratio = float(np.sqrt(np.mean(err**2)) / np.sqrt(np.mean(sd**2)))
    assert 1 / 1.5 < ratio < 1.5, (ratio, err, sd)


def test_the_triads_agree_within_1_mg_on_held_out_blocks_after_calibration(runs):
    for result, _ in runs:
        a = result.triads[0].agreement
        assert a.held_out_rms_mg < 1.0
        assert float(np.max(a.held_out_mg)) < 2.0
        # Before calibration the triads were far apart (biases of 50 mg, 3 % scales, 3 deg).
        assert a.before_rms_mg > 30.0


def test_the_gyroscopes_rotation_from_the_turns_is_the_imus_and_honest(runs):
    """M14: the second IMU's gyroscope turned as its accelerometer is (the truth's R), within
    0.05 deg, its 1-sigma within 1.5x of the error over seeds, and near the accelerometers'."""
    err, sd = [], []
    for result, truth in runs:
        g = result.triads[0].gyro_agreement
        assert g is not None and g.turns == 19  # every turn between the 20 poses
        err.append(angle_deg(g.rotation.R, truth.triads[0].R))
        sd.append(g.rotation.std_total_deg)
        assert g.accel_difference_deg < 0.05
    assert max(err) < 0.05, err
    ratio = float(np.sqrt(np.mean(np.square(err))) / np.sqrt(np.mean(np.square(sd))))
    assert 1 / 1.5 < ratio < 1.5, (ratio, err, sd)


def test_wahba_then_gauss_newton_recovers_a_large_rotation_exactly():
    rng = np.random.default_rng(3)
    v = rng.normal(size=(6, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    axis = np.array([1.0, 2.0, -0.5]) / np.linalg.norm([1.0, 2.0, -0.5])
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    th = np.radians(170.0)
    R = np.eye(3) + np.sin(th) * k + (1 - np.cos(th)) * k @ k
    u = v @ R.T
    assert angle_deg(kabsch(u, v, np.ones(6)), R) < 1e-6
    fit = fit_rotation(u + rng.normal(0, 1e-4, u.shape), v, np.full(6, 2e-8))
    assert angle_deg(fit.R, R) < 0.02
    # With noise of 1e-4 per axis and 6 directions, the standard error is about 1e-4 rad.
    assert 0.001 < fit.std_total_deg < 0.03


def test_a_low_range_triad_leaves_its_clipped_poses_out():
    """A 0.97 g range clips the poses with an axis near vertical: those blocks are left out of
    the rotation (flat at the limit is not gravity), the rest still give it."""
    result, truth = _run(2, range_g=0.97)
    assert result.triads[0].gyro is None  # an accelerometer alone: calibrated without one
    a = result.triads[0].agreement
    assert a is not None and a.blocks < 20
    assert angle_deg(a.rotation.R, truth.triads[0].R) < 0.1


def test_calib_json_holds_the_triads_section_and_the_report_says_it(runs):
    result, truth = runs[0]
    d = json.loads(json.dumps(result_to_dict(result)))
    (entry,) = d["triads"]["triads"]
    assert entry["accelerometer"] == "acc a2" and entry["gyroscope"] == "gyro g2"
    gr = entry["gyroscope_rotation"]
    assert angle_deg(np.array(gr["rotation_to_reference"]), truth.triads[0].R) < 0.05
    assert gr["turns"] == 19 and gr["rotation_std_deg"]["total"] > 0
    R = np.array(entry["rotation_to_reference"])
    assert angle_deg(R, truth.triads[0].R) < 0.05
    assert entry["rotation_std_deg"]["total"] > 0
    assert entry["agreement_mg"]["after_held_out"]["rms"] < 1.0
    # Its own parameters: the second triad's scales within 0.3 % of its truth.
    K = np.array(entry["segments"][0]["accelerometer"]["K"])
    np.testing.assert_allclose(K, truth.triads[0].model.K, rtol=3e-3)
    lines = [ln.text for ln in report(result).overview if ln.label == "triad"]
    assert lines and "acc a2: turned 3.0" in lines[0]
    assert "gyro g2: turned 3.0" in lines[1] and "from its accelerometer's rotation" in lines[1]


def test_one_triad_writes_no_triads_section():
    session, _ = make_session(poses=12, seed=1)
    result = calibrate(session)
    assert calibrate_triads(result).triads == ()
    assert "triads" not in result_to_dict(calibrate_triads(result))


def test_a_triad_named_that_the_session_lacks_is_one_line(runs):
    with pytest.raises(ImucalError, match="no other accelerometer triad 'a3'.*a2"):
        calibrate_triads(runs[0][0], ["a3"])


def test_a_triad_parameter_its_data_leave_undetermined_leaves_the_rotation_error_undetermined():
    """An undetermined M2 parameter has no finite error: neither has the rotation it moves."""
    from imucal.stages.triads import TriadModels, propagated_cov

    rng = np.random.default_rng(1)
    raw = rng.normal(size=(8, 3))
    raw /= np.linalg.norm(raw, axis=1, keepdims=True)
    params = np.r_[0, 0, 0, 1, 1, 1, 0, 0, 0].astype(float)
    cov = np.eye(9) * 1e-8
    used = np.ones(8, bool)
    models = TriadModels(raw, np.zeros(8, int), (params,), (cov,), 1.0)
    finite = propagated_cov(models, 1, raw, raw, np.full(8, 1e-8), used, np.eye(3))
    assert np.all(np.isfinite(finite)) and np.trace(finite) > 0
    cov[0, 0] = np.inf
    models = TriadModels(raw, np.zeros(8, int), (params,), (cov,), 1.0)
    assert np.all(np.isinf(propagated_cov(models, 1, raw, raw, np.full(8, 1e-8), used,
                                          np.eye(3))))


def test_three_imus_named_as_a_log_names_them_in_other_units():
    """Three IMUs as a flight controller's log holds them (sensor_accel:N with its gyroscope
    by IMU, in m/s^2 while the reference is in g): each paired with its own gyroscope, each
    turned by its own rotation, chosen by IMU name."""
    import dataclasses

    from imucal.session import STANDARD_GRAVITY

    session, truth = make_session(poses=20, seed=5, acc_rate=200.0, second_acc=(
        SecondTriad(rate=400.0, gyro=True), SecondTriad(rate=250.0, rotation_deg=10.0,
                                                        gyro=True)))
    renamed = []
    for s in session.others:
        n = s.instance[1]
        imu = f"sensor_accel:{n}+sensor_gyro:{n}"
        if s.kind == "acc":
            renamed.append(dataclasses.replace(s, instance=f"sensor_accel:{n}", imu=imu,
                                               values=s.values * STANDARD_GRAVITY, unit="m/s^2"))
        else:
            renamed.append(dataclasses.replace(s, instance=f"sensor_gyro:{n}", imu=imu))
    session = dataclasses.replace(session, others=tuple(renamed))
    base = calibrate(session)
    result = calibrate_triads(base)
    assert [(t.name, t.gyro) for t in result.triads] == [
        ("acc sensor_accel:2", "gyro sensor_gyro:2"), ("acc sensor_accel:3", "gyro sensor_gyro:3")]
    for tri, tt in zip(result.triads, truth.triads):
        assert tri.result.calibration.acc_unit == "m/s^2"
        assert angle_deg(tri.agreement.rotation.R, tt.R) < 0.05
        assert angle_deg(tri.gyro_agreement.rotation.R, tt.R) < 0.05
        assert tri.agreement.held_out_rms_mg < 1.0
    assert result.triads[1].agreement.angle_deg == pytest.approx(10.0, abs=0.05)
    (only,) = calibrate_triads(base, ["sensor_accel:3+sensor_gyro:3"]).triads
    assert only.name == "acc sensor_accel:3"


def test_a_noisy_triad_fitted_to_the_reference_s_gravity_vectors():
    """M15: a triad with 10 times the reference's noise (a high-range part), fitted to the
    reference's calibrated vectors, has its scales and bias closer to the truth than its own
    norm-only fit, and standard errors that say so honestly (errors over 12 seeds within 1.5x
    of them)."""
    own_k, vec_k, own_b, vec_b, z = [], [], [], [], []
    for seed in range(12):
        session, truth = make_session(poses=20, seed=seed, acc_rate=200.0,
                                      second_acc=SecondTriad(rate=400.0, noise=0.03))
        (tri,) = calibrate_triads(calibrate(session)).triads
        v, tt, own = tri.against_reference, truth.triads[0], tri.result.segments[0].acc.model
        assert angle_deg(v.R, tt.R) < 0.1
        own_k += list(own.K / tt.model.K - 1)
        vec_k += list(v.model.K / tt.model.K - 1)
        own_b += list(own.b - tt.model.b)
        vec_b += list(v.model.b - tt.model.b)
        z += list((v.model.K - tt.model.K) / v.std_K) + list((v.model.b - tt.model.b) / v.std_b)

    def rms(x):
        return float(np.sqrt(np.mean(np.square(x))))

    assert rms(vec_k) < 0.8 * rms(own_k) and rms(vec_b) < 0.6 * rms(own_b)
    assert rms(vec_b) < 0.5e-3  # g: half a mg
    assert 1 / 1.5 < rms(z) < 1.5


@pytest.mark.parametrize("offset", [0.5, -1.5])
def test_a_triad_on_another_clock_is_put_on_the_reference_s(offset):
    """Logged by another device: its clock half a second ahead (or 1.5 s behind). The offset is
    measured from the motion within 10 ms, said, and the comparisons are as on one clock."""
    import dataclasses

    session, truth = make_session(poses=20, seed=3, acc_rate=200.0,
                                  second_acc=SecondTriad(rate=400.0, gyro=True))
    session = dataclasses.replace(session, others=tuple(
        dataclasses.replace(s, t=s.t + offset) for s in session.others))
    (tri,) = calibrate_triads(calibrate(session)).triads
    assert tri.clock_offset_s == pytest.approx(offset, abs=0.01)
    assert "its clock reads" in tri.said[0]
    assert angle_deg(tri.agreement.rotation.R, truth.triads[0].R) < 0.05
    assert tri.agreement.held_out_rms_mg < 1.0
    assert angle_deg(tri.gyro_agreement.rotation.R, truth.triads[0].R) < 0.05


def test_clock_offset_of_a_signal_against_itself():
    from imucal.stages.triads import clock_offset

    session, _ = make_session(poses=20, seed=4, acc_rate=200.0)
    for lag in (0.0, 0.123, -2.0):
        off, corr = clock_offset(session.t_acc, session.acc, session.t_acc + lag, session.acc)
        assert off == pytest.approx(lag, abs=0.005) and corr > 0.95  # half a 10 ms cell
    # Too little time shared to look 5 s either way: not compared.
    short = slice(0, 300)
    off, corr = clock_offset(session.t_acc[short], session.acc[short], session.t_acc[short],
                             session.acc[short])
    assert np.isnan(off) and corr == 0.0


def test_the_motion_envelope_is_the_same_read_a_chunk_at_a_time(monkeypatch):
    from imucal.stages import triads

    session, _ = make_session(poses=6, seed=2, acc_rate=200.0)
    grid = np.arange(session.t_acc[0], session.t_acc[-1], triads.ENVELOPE_STEP_S)
    whole = triads.motion_envelope(session.t_acc, session.acc, grid)
    monkeypatch.setattr(triads, "ENVELOPE_ROWS", 333)
    np.testing.assert_allclose(triads.motion_envelope(session.t_acc, session.acc, grid), whole,
                               rtol=1e-12, atol=1e-12)
    assert whole.max() > 0.5  # the turns: tenths of a radian a second and more
    assert np.median(whole) < whole.max() / 10  # the poses: still
