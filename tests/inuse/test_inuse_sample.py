"""The check on the bundled sample: a calibration holds on the recording it was fitted on
(its still poses are moments of use too), with or without the gyroscope."""

from __future__ import annotations

import dataclasses

import imucal
from imucal.inuse.check import HOLDS, NOT_CHECKED, check
from imucal.io.inuse_file import read_for_check


def test_a_calibration_holds_on_its_own_recording(sample_session_path, tmp_path):
    session = imucal.load_session(sample_session_path)
    imucal.save_calibration(imucal.calibrate(session), tmp_path / "calib.json")
    cal, stored, _ = read_for_check(tmp_path / "calib.json")
    assert 0.1 < stored.static_norm_mg < 0.5  # the held-out figure of §5 (0.21 mg)
    assert 2e-4 < stored.acc_noise_density < 4e-4  # g/sqrt(Hz), from the still blocks (A1)
    got = check(cal, stored, session)
    assert got.level == HOLDS and got.exit_code == 0, got.reason
    assert got.moments.count >= 30 and got.moments.orientations >= 25  # of 36 poses held 3.5 s
    assert got.parts[0].value < 0.5  # mg: the calibration's own figure, about
    assert "the stored noise" in got.moments.level_from
    # without a gyroscope: the accelerometer alone is judged
    acc_only = dataclasses.replace(session, gyro=None, t_gyro=None, gyro_unit=None)
    got = check(cal, stored, acc_only)
    assert got.parts[1].level == NOT_CHECKED and got.level == HOLDS
