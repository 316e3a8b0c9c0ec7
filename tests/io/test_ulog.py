"""PX4 ULog (imucal.io.formats.ulog): the shared flight log read into streams and checked against
pyulog's own reading of it (``ULog(path).data_list``), the compiled walk against pyulog's
parser, and the refusals a user meets (a cut file, a log without sensor topics)."""

from __future__ import annotations

import hashlib
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from imucal.errors import ImucalError
from imucal.io.formats import read_streams, sniff
from imucal.io.formats import ulog as ulog_reader

SHA256 = "68d1020f688109f027dba08d2950247cc0ae34aaefdcf37e4a7d60838f3e1aa3"
NAMES = ["acc sensor_accel:0", "temp sensor_accel:0", "acc sensor_accel:1",
         "temp sensor_accel:1", "acc sensor_accel:2", "temp sensor_accel:2",
         "gyro sensor_combined", "acc sensor_combined", "gyro sensor_gyro:0",
         "gyro sensor_gyro:1", "gyro sensor_gyro:2", "mag sensor_mag:0", "mag sensor_mag:1"]


@pytest.fixture(scope="module")
def ulg(shared_data: Path) -> Path:
    return shared_data / "px4_ulog" / "sample_log_small.ulg"


@pytest.fixture(scope="module")
def streams(ulg: Path):
    return read_streams(ulg, sniff(ulg.read_bytes()[:16], ulg), "sample_log_small.ulg")


@pytest.fixture(scope="module")
def reference(ulg: Path) -> dict:
    """pyulog's own reading, topic by topic: the independent truth here."""
    from pyulog import ULog

    return {(d.name, d.multi_id): d.data for d in ULog(str(ulg)).data_list}


def _by_name(streams) -> dict:
    return {s.name: s for s in streams.streams}


def test_shared_log_streams_named_counted_and_hashed(ulg, streams, reference):
    assert hashlib.sha256(ulg.read_bytes()).hexdigest() == SHA256 == streams.sha256
    assert streams.format == "PX4 ULog"
    assert [s.name for s in streams.streams] == NAMES
    s = _by_name(streams)
    for i in range(3):
        assert s[f"acc sensor_accel:{i}"].samples == len(reference[("sensor_accel", i)]["x"]) == 6
        assert s[f"gyro sensor_gyro:{i}"].samples == 6
        # the three IMUs log sensor_accel/gyro once a second in this flight
        assert s[f"acc sensor_accel:{i}"].rate == pytest.approx(1.0, abs=0.001)
        assert s[f"acc sensor_accel:{i}"].imu == s[f"gyro sensor_gyro:{i}"].imu == \
            f"sensor_accel:{i}+sensor_gyro:{i}"
    assert s["acc sensor_combined"].samples == len(reference[("sensor_combined", 0)]["timestamp"])
    assert s["acc sensor_combined"].samples == 1298
    assert s["gyro sensor_combined"].rate == pytest.approx(1e6 / 4888, rel=1e-3)  # ~204.6 Hz
    assert {x.unit for x in streams.of_kind("acc")} == {"m/s^2"}
    assert {x.unit for x in streams.of_kind("gyro")} == {"rad/s"}
    assert {x.unit for x in streams.of_kind("mag")} == {"gauss"}
    assert {x.unit for x in streams.of_kind("temp")} == {"degC"}
    assert s["acc sensor_accel:0"].frame.startswith("FRD (PX4 board frame")
    assert s["acc sensor_combined"].frame.startswith("FRD (PX4 body frame")
    assert s["acc sensor_accel:0"].time_source.startswith("timestamp_sample")
    assert s["acc sensor_combined"].time_source.startswith(
        "timestamp + accelerometer_timestamp_relative")
    # the chips: bus, address and device type decoded from PX4's device_id
    assert s["acc sensor_accel:0"].device == "0x25000a (SPI bus 1, address 0x00, devtype 0x25)"
    assert s["mag sensor_mag:1"].device == "0x90c09 (I2C bus 1, address 0x0c, devtype 0x09)"
    # one chip, one thermometer: the gyroscopes' copies are not repeated
    assert sum("temperature identical" in n for n in streams.notes) == 3
    # the logger's dropout messages, as pyulog counts them
    from pyulog import ULog

    drops = ULog(str(ulg)).dropouts
    assert streams.notes[0] == (f"the logger dropped data {len(drops)} time "
                                f"({sum(d.duration for d in drops)} ms in all): every topic has "
                                "gaps there") == ("the logger dropped data 1 time (30 ms in "
                                                  "all): every topic has gaps there")


def test_values_and_times_are_pyulogs(streams, reference):
    s = _by_name(streams)
    for i in range(3):
        ref = reference[("sensor_accel", i)]
        acc = s[f"acc sensor_accel:{i}"]
        np.testing.assert_array_equal(acc.t, ref["timestamp_sample"] / 1e6)
        np.testing.assert_array_equal(acc.values, np.column_stack([ref["x"], ref["y"],
                                                                   ref["z"]]))
        np.testing.assert_array_equal(s[f"temp sensor_accel:{i}"].values[:, 0],
                                      ref["temperature"])
        gref = reference[("sensor_gyro", i)]
        np.testing.assert_array_equal(s[f"gyro sensor_gyro:{i}"].values[-1],
                                      [gref["x"][-1], gref["y"][-1], gref["z"][-1]])
    # the heated IMU (about 40 deg C) and the two others at 28-30 deg C
    assert s["temp sensor_accel:0"].values[0, 0] == pytest.approx(40.02537, abs=1e-5)
    assert 28 < s["temp sensor_accel:1"].values[0, 0] < 30
    assert s["acc sensor_accel:0"].values[0] == pytest.approx([0.6821298, 0.24333796,
                                                               -9.696953], abs=1e-6)
    ref = reference[("sensor_combined", 0)]
    acc = s["acc sensor_combined"]
    np.testing.assert_array_equal(
        acc.t, (ref["timestamp"] + ref["accelerometer_timestamp_relative"]) / 1e6)
    np.testing.assert_array_equal(acc.values[[0, -1]], np.array(
        [[ref[f"accelerometer_m_s2[{k}]"][j] for k in range(3)] for j in (0, -1)]))
    gyro = s["gyro sensor_combined"]
    np.testing.assert_array_equal(gyro.t, ref["timestamp"] / 1e6)
    assert gyro.values[0] == pytest.approx([0.00296838, 0.00364624, 0.0009425], abs=1e-8)
    mag = reference[("sensor_mag", 0)]
    np.testing.assert_array_equal(s["mag sensor_mag:0"].values[:, 2], mag["z"])


def test_compiled_walk_equals_pyulogs_parser(ulg, streams):
    slow = ulog_reader.read_streams(ulg, "x", None, fast=False)
    assert [s.name for s in slow.streams] == [s.name for s in streams.streams]
    for a, b in zip(streams.streams, slow.streams):
        np.testing.assert_array_equal(a.t, b.t)
        np.testing.assert_array_equal(a.values, b.values)
        assert (a.device, a.imu, a.unit) == (b.device, b.imu, b.unit)


def test_keep_decodes_only_the_chosen_instance(ulg):
    got = ulog_reader.read_streams(ulg, "x", lambda inst: inst == "sensor_accel:1")
    assert [s.name for s in got.streams] == ["acc sensor_accel:1", "temp sensor_accel:1"]
    # a gyroscope alone: no partner read, so it stands as its own IMU, with the thermometer
    got = ulog_reader.read_streams(ulg, "x", lambda inst: inst == "sensor_gyro:2")
    assert [(s.name, s.imu) for s in got.streams] == [("gyro sensor_gyro:2", "sensor_gyro:2"),
                                                      ("temp sensor_gyro:2", "sensor_gyro:2")]


def test_truncated_log_is_read_to_the_cut_and_says_so(ulg, tmp_path):
    from pyulog import ULog

    cut = tmp_path / "cut.ulg"
    cut.write_bytes(ulg.read_bytes()[:500_003])
    got = ulog_reader.read_streams(cut, "cut.ulg", None)
    assert got.notes[0].startswith("truncated: the file ends inside a message (byte 499963, "
                                   "40 bytes of it present)")
    # pyulog reads the same cut file silently (no corruption flag): the same samples
    ref = {(d.name, d.multi_id): d.data for d in ULog(str(cut)).data_list}
    combined = _by_name(got)["acc sensor_combined"]
    assert combined.samples == len(ref[("sensor_combined", 0)]["timestamp"]) < 1298
    np.testing.assert_array_equal(combined.values[-1], [
        ref[("sensor_combined", 0)][f"accelerometer_m_s2[{k}]"][-1] for k in range(3)])


@pytest.mark.parametrize(("size", "expected"), [
    (10, "a ULog starts with a 16-byte header; the file has 10 bytes"),
    (16, "the file holds a ULog header and no message"),
    (20_000, "truncated: the file ends inside a message (byte 19992, 8 bytes of it present), "
             "before any sensor topic is logged"),
    (62_000, "truncated: the file ends inside a message (byte 61989, 11 bytes of it present), "
             "before any sensor sample"),
])
def test_log_cut_before_sensor_data_is_refused(ulg, tmp_path, size, expected):
    cut = tmp_path / "cut.ulg"
    cut.write_bytes(ulg.read_bytes()[:size])
    with pytest.raises(ImucalError) as err:
        ulog_reader.read_streams(cut, "cut.ulg", None)
    assert str(err.value) == f"cut.ulg: {expected}"


@pytest.mark.parametrize("fast", [True, False])
def test_log_without_sensor_topics_is_refused_naming_what_it_has(ulg, tmp_path, fast):
    from pyulog import ULog

    path = tmp_path / "attitude_only.ulg"
    ULog(str(ulg), message_name_filter_list=["vehicle_attitude", "cpuload"]).write_ulog(
        str(path))
    with pytest.raises(ImucalError) as err:
        ulog_reader.read_streams(path, "attitude_only.ulg", None, fast=fast)
    assert str(err.value) == (
        "attitude_only.ulg: no sensor topic (sensor_accel, sensor_gyro, sensor_mag, "
        "sensor_combined) in the log; it has 2 topics: cpuload, vehicle_attitude")


def test_irregular_message_falls_back_to_pyulog(ulg, tmp_path, streams):
    """A message of a type no writer makes, spliced between two messages: the compiled walk
    stops there and pyulog's parser (which skips it) reads the file, saying so."""
    from imucal.io.formats import ulog_scan

    data = np.fromfile(ulg, dtype=np.uint8)
    offsets, _, _ = ulog_scan.message_offsets(data, 16)
    at = int(offsets[len(offsets) // 2])
    odd = bytes([6, 0, ord("Z")]) + b"abcdef"
    path = tmp_path / "odd.ulg"
    path.write_bytes(data[:at].tobytes() + odd + data[at:].tobytes())
    got = ulog_reader.read_streams(path, "odd.ulg", None)
    assert got.notes[0] == (f"a message header no ULog writer makes at byte {at} (type 90, "
                            "size 6): read by pyulog's parser, which skips what it cannot read")
    for a, b in zip(got.streams, streams.streams):
        assert a.name == b.name
        np.testing.assert_array_equal(a.values, b.values)


def test_device_id_decoded_as_px4_packs_it():
    # bus type bits 0-2, bus 3-7, address 8-15, devtype 16-23
    assert ulog_reader.describe_device(0x280022) == \
        "0x280022 (SPI bus 4, address 0x00, devtype 0x28)"
    assert ulog_reader.describe_device((0x75 << 16) | (0x68 << 8) | (2 << 3) | 1) == \
        "0x756811 (I2C bus 2, address 0x68, devtype 0x75)"


def test_readers_import_their_libraries_only_when_reading():
    code = ("import sys, imucal.io.formats.ulog, imucal.io.formats.dataflash; "
            "print(sorted(m for m in ('pyulog', 'pymavlink', 'numba') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, timeout=60)
    assert out.stdout.strip() == "[]"


def test_topic_in_an_unknown_layout_is_a_note_not_a_crash():
    t = np.array([1_000_000, 2_000_000], dtype=np.uint64)
    old = ulog_reader._Topic("sensor_gyro", 0, {"timestamp": t, "x": np.zeros(2),
                                                 "y": np.zeros(2)})
    notes: list[str] = []
    assert ulog_reader._streams([old], notes) == []
    assert notes == ["sensor_gyro:0: no field z (a PX4 layout this reader does not know); "
                     "not read"]


def test_older_px4_layout_says_the_driver_calibrated():
    t = np.array([1_000_000, 2_000_000], dtype=np.uint64)
    old = ulog_reader._Topic("sensor_accel", 0, {"timestamp": t, "integral_dt": t,
                                                  "x": np.zeros(2), "y": np.zeros(2),
                                                  "z": np.array([-9.8, -9.7])})
    (acc,) = ulog_reader._streams([old], [])
    assert acc.time_source == "timestamp (µs since boot)"  # no timestamp_sample in that layout
    np.testing.assert_array_equal(acc.t, [1.0, 2.0])
    assert acc.values[:, 2].tolist() == [-9.8, -9.7]
    assert acc.notes == ("sensor_accel:0: an older PX4 layout (x_raw/integral_dt), whose driver "
                         "applied PX4's calibration (CAL_ACCn/CAL_GYROn) already",)
