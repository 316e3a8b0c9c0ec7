"""``imucal inspect`` on every shared recording of the new formats: one row per stream, as its
reader finds it (each reader's own test checks the reader against the format's library), with
what the other commands would take marked, and exit 0."""

from __future__ import annotations

import json

import pytest

from imucal.cli import main
from imucal.io.logs import log_format, read_log

FILES = {  # file -> (format shown, streams it must list, the pair taken by default)
    "ros1_imu_tools/phidgets_imu_upside_down.bag":
        ("ROS 1 bag", {"acc /imu/data_raw", "gyro /imu/data_raw", "mag /imu/mag"},
         {"acc /imu/data_raw", "gyro /imu/data_raw", "mag /imu/mag"}),
    "ros1_imu_tools/sparkfun_razor.bag": ("ROS 1 bag", None, None),
    "px4_ulog/sample_log_small.ulg":
        ("PX4 ULog", {f"{k} sensor_{n}:{i}" for i in range(3)
                      for k, n in (("acc", "accel"), ("gyro", "gyro"))}
         | {"acc sensor_combined", "gyro sensor_combined", "mag sensor_mag:0"},
         {"acc sensor_accel:0", "gyro sensor_gyro:0", "mag sensor_mag:0"}),
    "ardupilot_dataflash/test.BIN":
        ("ArduPilot DataFlash log", {"acc IMU", "gyro IMU", "acc IMU2", "gyro IMU2", "temp IMU",
                                     "mag MAG", "mag MAG2", "mag MAG3"},
         {"acc IMU", "gyro IMU", "mag MAG"}),
    "broad/02_undisturbed_slow_rotation_B.hdf5":
        ("HDF5", {"acc imu_acc", "gyro imu_gyr", "mag imu_mag"},
         {"acc imu_acc", "gyro imu_gyr", "mag imu_mag"}),
    "sunsided_mpu6050_hmc5883l/full-sphere/hmc5883l_compass.mat":
        ("HDF5", {"mag compassBuffer"}, set()),
}


@pytest.mark.parametrize("name", sorted(FILES))
def test_inspect_lists_every_stream(shared_data, name, capsys):
    path = shared_data / name
    shown, must, picked = FILES[name]
    assert main(["inspect", str(path), "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)[0]
    assert listed["format"] == shown and listed["error"] is None
    rows = {f"{s['kind']} {s['name']}": s for s in listed["streams"]}
    if must is not None:
        assert must <= set(rows)
    if picked is not None:
        assert {k for k, s in rows.items() if s["picked"]} == picked
    ref = read_log(path, log_format(path), path.name)
    assert len(rows) == len(ref.streams)
    for s in ref.streams:
        row = rows[s.name]
        assert row["samples"] == s.samples and row["unit"] == s.unit
        assert row["duration_s"] == pytest.approx(s.duration)


def test_inspect_of_the_csv_with_a_magnetometer(shared_data, capsys):
    assert main(["inspect", str(shared_data / "xio_fusion" / "sensor_data.csv")]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0] == "sensor_data.csv (table): 3 streams"
    assert out[3].split()[:5] == ["*", "mag", "m", "13514", "samples"]
