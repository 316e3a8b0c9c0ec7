"""The check and the refresh on real sensors: three MPU-9150 units (mikoff_mpu9150), each
calibrated on its own recording. A unit's calibration holds on its own recording and not on
another unit's; refreshed from half of another unit's recording, it holds on the other half."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import imucal
from imucal.inuse.check import DRIFTED, HOLDS, check
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
