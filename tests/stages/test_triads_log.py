"""The shared PX4 flight log (three IMUs at different temperatures, method.md §11): every IMU
read and their disagreement said, and the flight not calibrated (it holds no still poses)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from imucal.errors import ImucalError
from imucal.io.inspect import as_text, inspect_file
from imucal.io.load import load_session
from imucal.pipeline import calibrate
from imucal.stages.triads import logged_imus
from imucal.streams import Stream

ULOG = Path("/work/shared/data/px4_ulog/sample_log_small.ulg")
pytestmark = pytest.mark.skipif(not ULOG.exists(), reason="the shared PX4 log is not here")


def test_every_imu_of_the_flight_read_and_their_disagreement_said():
    session = load_session(ULOG)
    ref = Stream("acc", "sensor_accel:0", session.t_acc, session.acc, session.acc_unit,
                 "the chosen accelerometer", imu="sensor_accel:0+sensor_gyro:0")
    accs = [ref] + [s for s in session.others if s.kind == "acc"]
    imus = logged_imus(accs, [s for s in session.others if s.kind == "temp"])
    names = [i.name for i in imus]
    assert names[:3] == ["acc sensor_accel:0", "acc sensor_accel:1", "acc sensor_accel:2"]
    temps = [i.temperature for i in imus[:3]]
    assert temps[0] == pytest.approx(40.2, abs=0.5)  # the heated one
    assert all(27 < t < 31 for t in temps[1:])
    diffs = [i.difference for i in imus]
    assert diffs[0] == 0.0
    # Each IMU's mean is gravity, |a| within 2 % of 9.81 m/s^2, and the three disagree by
    # tenths of a m/s^2: a flight's numbers, not a calibration's.
    for i in imus[:3]:
        assert np.linalg.norm(i.mean) == pytest.approx(9.81, rel=0.02)
    assert 0.05 < diffs[1] < 0.7 and 0.01 < diffs[2] < 0.7
    # Over the time both cover: sensor_accel:1 starts 0.9 ms before the reference and stops
    # 1.3 ms before it, so each loses one sample of its six.
    one = accs[1]
    shared = session.t_acc <= one.t[-1]
    mine = one.t >= session.t_acc[0]
    assert shared.sum() == mine.sum() == 5
    want = np.linalg.norm(one.values[mine].mean(axis=0) - session.acc[shared].mean(axis=0))
    assert diffs[1] == pytest.approx(want, abs=1e-12)


def test_inspect_says_it_and_a_flight_is_not_calibrated():
    text = "\n".join(as_text(inspect_file(ULOG)))
    assert "4 accelerometers as logged, against acc sensor_accel:0" in text
    assert "a flight, cannot calibrate them" in text
    assert "acc sensor_accel:1: 6 samples" in text and "28.3 degC" in text
    assert "differs from the reference by 0.373 m/s^2" in text
    assert "stated in another frame (FRD (PX4 body frame" in text  # sensor_combined
    with pytest.raises(ImucalError):
        calibrate(load_session(ULOG))


@pytest.mark.parametrize("more", [(), ("--temperature",)])
def test_calibrate_all_imus_on_the_flight_is_one_line_pointing_to_inspect(tmp_path, more):
    """What is missing named in one line: still poses in many orientations (the flight's IMUs
    at three temperatures do not change that)."""
    import subprocess
    import sys

    code = "import sys; from imucal.cli import main; sys.exit(main())"
    proc = subprocess.run([sys.executable, "-c", code, "calibrate", str(ULOG), "--out",
                           str(tmp_path / "c.json"), "--all-imus", *more], capture_output=True,
                          text=True, timeout=180)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    (line,) = proc.stderr.strip().splitlines()
    assert line.startswith("imucal: error: sample_log_small.ulg: static blocks: found 1 static "
                           "block of at least 3 samples (3 s) in 1 distinct orientation; ")
    assert ("the accelerometer model needs 9 or more distinct still orientations (6 at the "
            "least, the prior holding the rest)") in line
    assert line.endswith("imucal inspect shows how the file's IMUs disagree as logged")
    assert not (tmp_path / "c.json").exists()


def test_the_flights_layout_synthetic_before_and_after_a_calibration():
    """A flight holds no still poses in many orientations, so its IMUs cannot be calibrated
    from it (the test above: one line naming what is missing). What a calibration does for
    that layout is measured on a synthetic session of it: the flight's three IMUs (its
    reference sensor_accel:0, and sensor_accel:1 and :2 each with its gyroscope, in m/s^2,
    turned 3 and 10 deg from it), recorded still in 20 poses. Before: their raw still-block
    gravity disagrees by 0.8-1.9 m/s^2 (PX4 refuses to arm beyond 0.7); calibrated and turned
    into the reference's frame, within 1 mg held out, and the rotation PX4 has no parameter
    for is what would remain (0.4 and 1.3 m/s^2)."""
    import dataclasses

    from imucal.pipeline import calibrate_triads
    from imucal.session import STANDARD_GRAVITY
    from imucal.stages.triads import angle_deg
    from imucal.synth import SecondTriad, make_session

    flight = load_session(ULOG)
    layout = sorted({s.imu for s in flight.others if s.kind == "acc" and s.imu
                     and s.imu.startswith("sensor_accel:")})
    assert layout == ["sensor_accel:1+sensor_gyro:1", "sensor_accel:2+sensor_gyro:2"]
    assert flight.acc_unit == "m/s^2" and all(
        any(g.kind == "gyro" and g.imu == imu for g in flight.others) for imu in layout)

    session, truth = make_session(poses=20, seed=5, acc_rate=200.0, acc_unit="m/s^2",
                                  second_acc=(SecondTriad(rate=400.0, gyro=True),
                                              SecondTriad(rate=250.0, rotation_deg=10.0,
                                                          gyro=True)))
    renamed = []
    for s in session.others:  # a2, g2, a3, g3 named as the flight's IMUs 1 and 2
        imu = layout[int(s.instance[1]) - 2]
        acc_name, gyro_name = imu.split("+")
        renamed.append(dataclasses.replace(s, instance=acc_name if s.kind == "acc"
                                           else gyro_name, imu=imu))
    session = dataclasses.replace(session, others=tuple(renamed))
    result = calibrate_triads(calibrate(session))
    mps2 = STANDARD_GRAVITY / 1e3  # per mg
    figures = []
    for tri, tt, imu in zip(result.triads, truth.triads, layout):
        a = tri.agreement
        assert tri.name == f"acc {imu.split('+')[0]}" and tri.gyro == f"gyro {imu.split('+')[1]}"
        before = a.before_rms_mg * mps2
        unrotated = float(np.sqrt(np.mean(a.unrotated_mg**2))) * mps2
        after = a.held_out_rms_mg * mps2
        figures.append((before, unrotated, after))
        assert angle_deg(a.rotation.R, tt.R) < 0.05
        assert a.held_out_rms_mg < 1.0 and before > 50 * after
        # Calibrated but left in its own frame, it is off by the true rotation: |u - R' u|.
        u = a.u / np.linalg.norm(a.u, axis=1)[:, None]
        turned = float(np.sqrt(np.mean(np.linalg.norm(u - u @ tt.R, axis=1) ** 2))) * 1e3
        assert unrotated == pytest.approx(turned * mps2, abs=2 * mps2)
    (b1, u1, _), (b2, u2, _) = figures
    assert 0.7 < b1 < 2.5 and 0.7 < b2 < 2.5  # beyond PX4's arming limit before
    assert 0.3 < u1 < 0.5 and 1.2 < u2 < 1.6  # a rotation PX4 cannot hold: what it leaves
