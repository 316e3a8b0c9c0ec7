"""The check and the refresh on real sensors: three MPU-9150 units (mikoff_mpu9150), each
calibrated on its own recording. A unit's calibration holds on its own recording and not on
another unit's; refreshed from half of another unit's recording, it holds on the other half."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import imucal
from imucal.inuse.check import DRIFTED, HOLDS, Stored, check
from imucal.inuse.refresh import refresh
from imucal.io.inuse_file import read_for_check
from imucal.stages.apply import Calibration


@pytest.fixture(scope="module")
def units(shared_data, tmp_path_factory):
    d = tmp_path_factory.mktemp("mpu9150")
    sessions, cals = [], []
    for i in range(3):
        s = imucal.load_session(shared_data / "mikoff_mpu9150" / f"imu{i}.log", rate=100.0)
        sessions.append(s)
        if i < 2:  # two calibrations (a calibrate is the slow part)
            imucal.save_calibration(imucal.calibrate(s), d / f"imu{i}.json")
            cals.append(read_for_check(d / f"imu{i}.json")[:2])
    return sessions, cals


def test_a_units_calibration_holds_on_it_and_not_on_the_others(units):
    sessions, cals = units
    for c, (cal, stored) in enumerate(cals):
        assert stored.static_norm_mg is not None and stored.acc_noise_density is not None
        for r, session in enumerate(sessions):
            got = check(cal, stored, session)
            assert got.level == (HOLDS if r == c else DRIFTED), (c, r, got.reason)
            if r != c:  # another unit: its gyroscope bias is off by 0.5-1.7 deg/s
                assert got.parts[1].level == DRIFTED
            else:
                assert got.moments.count >= 18 and got.parts[0].value < 0.5  # mg


def test_refreshed_on_one_half_it_holds_on_the_other(units):
    """imu0's calibration on imu2 (a 24 mg still-norm error and a 0.5 deg/s bias), refreshed
    from the first half of imu2's recording, judged on the second half it did not see."""
    sessions, cals = units
    cal, stored = cals[0]
    s = sessions[2]
    half = s.t_acc[-1] / 2

    def part(first: bool):
        k = (s.t_acc < half) if first else (s.t_acc >= half)
        return dataclasses.replace(s, acc=s.acc[k], t_acc=s.t_acc[k], gyro=s.gyro[k],
                                   t_gyro=s.t_gyro[k])

    fresh = refresh(cal, stored, part(True))
    seg = dataclasses.replace(cal.segments[-1], acc=fresh.acc, gyro=fresh.gyro)
    new = Calibration(segments=(seg,), acc_unit_raw=cal.acc_unit_raw, acc_unit=cal.acc_unit,
                      g=cal.g, gyro_unit_raw=cal.gyro_unit_raw)
    before, after = check(cal, stored, part(False)), check(new, stored, part(False))
    assert before.level == DRIFTED and before.parts[0].value > 15  # measured 23.5 mg
    assert after.level == HOLDS and after.parts[0].value < 2.0  # measured 1.54 mg
    assert np.degrees(np.abs(before.gyro.rate)).max() > 0.4  # measured 0.54 deg/s
    assert np.degrees(np.abs(after.gyro.rate)).max() < 0.05  # measured 0.025 deg/s
    # unchanged parameters exactly as stored
    assert np.array_equal(fresh.acc.T, cal.segments[-1].acc.T)
    assert np.array_equal(fresh.gyro.T, cal.segments[-1].gyro.T)
    assert np.array_equal(fresh.gyro.K, cal.segments[-1].gyro.K)


def test_a_bias_refreshed_from_the_breaks_of_a_broad_trial_agrees_with_the_optical_reference(
        shared_data):
    """BROAD trial 05: slow rotations with still breaks, between still phases. The bias
    refreshed from the movement phase alone (its breaks are the only moments there) agrees with
    the still phases' mean rate within 0.01 deg/s, and the rate integrated with it over 10 s
    windows of the motion ends as far from the optical reference's rotation as with theirs
    (0.46 against 0.45 deg median; 2.96 deg with no bias removed)."""
    import h5py

    from imucal.models import SensorModel
    from imucal.numerics import quaternion as quat
    from imucal.numerics.rk4.intervals import integrate_transitions
    from imucal.stages.apply import SegmentModels

    path = shared_data / "broad" / "05_undisturbed_slow_rotation_with_breaks_B.hdf5"
    s = imucal.load_session(path)
    with h5py.File(path) as f:
        moving = np.asarray(f["movement"]).ravel().astype(bool)
        q_opt = np.asarray(f["opt_quat"])
    idx = np.flatnonzero(moving)
    a, b = idx[0], idx[-1] + 1
    ident = SensorModel(T=np.eye(3), K=np.ones(3), b=np.zeros(3))
    cal = Calibration(segments=(SegmentModels(0.0, 0.0, ident, ident),), acc_unit_raw="m/s^2",
                      acc_unit="m/s^2", g=9.80665, gyro_unit_raw="rad/s")
    motion = dataclasses.replace(s, acc=s.acc[a:b], t_acc=s.t_acc[a:b], gyro=s.gyro[a:b],
                                 t_gyro=s.t_gyro[a:b])
    fresh = refresh(cal, Stored(), motion)
    assert fresh.check.moments.count == 3  # the breaks
    b_rest = s.gyro[:a].mean(axis=0)  # the still phase before the motion
    assert np.degrees(np.abs(fresh.gyro.b - b_rest)).max() < 0.01  # measured 0.0047
    w = int(10 * s.acc_rate)
    starts = np.arange(a, b - w, w)
    ends = starts + w
    ok = np.isfinite(q_opt[starts]).all(axis=1) & np.isfinite(q_opt[ends]).all(axis=1)
    starts, ends = starts[ok], ends[ok]
    q_ref = quat.multiply(quat.conjugate(q_opt[starts]), q_opt[ends])

    def error(bias: np.ndarray) -> float:
        q = integrate_transitions(np.ascontiguousarray(s.gyro - bias), s.t_gyro, starts, ends)
        turn = quat.to_rotvec(quat.multiply(quat.conjugate(q), q_ref))
        return float(np.degrees(np.median(np.linalg.norm(turn, axis=1))))

    assert error(np.zeros(3)) > 2.0
    assert error(fresh.gyro.b) < 0.6 and abs(error(fresh.gyro.b) - error(b_rest)) < 0.05
