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


def test_calibrate_all_imus_on_the_flight_is_one_line_pointing_to_inspect(tmp_path):
    import subprocess
    import sys

    code = "import sys; from imucal.cli import main; sys.exit(main())"
    proc = subprocess.run([sys.executable, "-c", code, "calibrate", str(ULOG), "--out",
                           str(tmp_path / "c.json"), "--all-imus"], capture_output=True,
                          text=True, timeout=180)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    (line,) = proc.stderr.strip().splitlines()
    assert "distinct orientation" in line and line.endswith(
        "imucal inspect shows how the file's IMUs disagree as logged")
    assert not (tmp_path / "c.json").exists()
