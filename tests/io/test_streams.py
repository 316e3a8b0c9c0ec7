"""A session of many streams: choosing the pair to calibrate from a log (imucal.io.select), a
table's other streams (a2x…, mx…, temp), and ``imucal inspect``."""

from __future__ import annotations

import json

import numpy as np
import pytest

import imucal.io.logs as logs
from imucal.cli import main
from imucal.errors import ImucalError
from imucal.io.load import load_session
from imucal.io.select import choose, find, keep_for
from imucal.streams import Stream, StreamSet
from imucal.synth import make_session


def _stream(kind, instance, n=50, imu=None, rate=100.0, offset=0.0, unit=None):
    t = np.arange(n) / rate + offset
    width = 1 if kind == "temp" else 3
    values = np.arange(n * width, dtype=float).reshape(n, width) + offset
    return Stream(kind, instance, t, values, unit, f"log.bin: {instance}", imu=imu)


def _two_imus() -> StreamSet:
    return StreamSet("log.bin", "test", (
        _stream("acc", "IMU", imu="IMU"), _stream("gyro", "IMU", imu="IMU"),
        _stream("acc", "IMU2", imu="IMU2", offset=1.0), _stream("gyro", "IMU2", imu="IMU2"),
        _stream("mag", "MAG"), _stream("temp", "IMU2", imu="IMU2")))


def test_the_first_imu_is_taken_and_the_choice_said():
    c = choose(_two_imus(), {}, acc_only=False)
    assert (c.acc.instance, c.gyro.instance) == ("IMU", "IMU")
    assert [s.name for s in c.others] == ["acc IMU2", "gyro IMU2", "mag MAG", "temp IMU2"]
    assert c.said[0].startswith("accelerometer IMU chosen, the first of 2 (IMU, IMU2)")
    assert "of the same IMU" in c.said[1]


def test_a_named_accelerometer_brings_its_own_gyroscope():
    c = choose(_two_imus(), {"acc": "imu2"}, acc_only=False)  # case does not matter
    assert c.acc.instance == "IMU2" and c.acc.t[0] == 1.0
    assert c.gyro.instance == "IMU2"


def test_selectors_by_position_and_refusals_name_the_option():
    streams = _two_imus()
    assert find(streams, "acc", "1").instance == "IMU2"
    with pytest.raises(ImucalError) as info:
        find(streams, "gyro", "IMU3")
    assert str(info.value) == ("log.bin: --gyro: no gyroscope stream 'IMU3'; the file has: "
                               "IMU, IMU2 (imucal inspect lists every stream)")
    with pytest.raises(ImucalError, match="--mag: no magnetometer stream 'MAG9'"):
        choose(streams, {"mag": "MAG9"}, acc_only=False)
    no_gyro = StreamSet("a.bag", "test", (_stream("acc", "/imu"),))
    with pytest.raises(ImucalError, match="no gyroscope stream; name one with --gyro"):
        choose(no_gyro, {}, acc_only=False)
    assert choose(no_gyro, {}, acc_only=True).gyro is None
    with pytest.raises(ImucalError, match="no accelerometer stream to calibrate"):
        choose(StreamSet("m.bag", "test", (_stream("mag", "/mag"),)), {}, acc_only=False)


def test_a_reader_skips_what_the_selectors_cannot_match():
    assert keep_for({"acc": "/imu"}) is None  # a default gyroscope must be chosen among all
    keep = keep_for({"acc": "sensor_accel:1", "gyro": "sensor_gyro:1"})
    assert keep("sensor_accel:1") and keep("SENSOR_GYRO:1") and not keep("sensor_accel:0")
    assert keep_for({"acc": "0", "gyro": "0"}) is None


def test_a_log_loads_as_the_session_of_its_chosen_pair(monkeypatch):
    s, _ = make_session(poses=12, seed=3)
    streams = StreamSet("dev.bag", "test", (
        Stream("acc", "/other", s.t_acc, s.acc * 2, "g", "dev.bag: /other", imu="/other"),
        Stream("acc", "/imu", s.t_acc, s.acc * 9.80665, "m/s^2", "dev.bag: /imu", imu="/imu",
               frame="FLU (ROS REP 103)"),
        Stream("gyro", "/imu", s.t_gyro, np.rad2deg(s.gyro), "deg/s", "dev.bag: /imu",
               imu="/imu")))
    monkeypatch.setattr(logs, "log_format", lambda path: "ros1")
    monkeypatch.setattr(logs, "read_log", lambda path, key, source, keep=None: streams)
    import imucal.io.load as load

    monkeypatch.setattr(load, "log_format", lambda path: "ros1")
    path = _touch_file()
    sess = load_session(path, select={"acc": "/imu"})
    assert sess.acc_unit == "m/s^2"
    np.testing.assert_array_equal(sess.acc, s.acc * 9.80665)
    np.testing.assert_allclose(sess.gyro, s.gyro, rtol=1e-15, atol=1e-15)  # deg/s -> rad/s
    assert sess.chosen[0].startswith("acc /imu (dev.bag: /imu, m/s^2, frame FLU (ROS REP 103))")
    assert [o.name for o in sess.others] == ["acc /other"]


def _touch_file():
    import tempfile
    from pathlib import Path

    p = Path(tempfile.mkdtemp()) / "dev.bag"
    p.write_bytes(b"#ROSBAG V2.0\n")
    return p


def _table(tmp_path, extra: bool):
    s, _ = make_session(poses=14, seed=5)
    n = len(s.t_acc)
    cols = {"t": s.t_acc, "ax": s.acc[:, 0], "ay": s.acc[:, 1], "az": s.acc[:, 2],
            "gx": s.gyro[:, 0], "gy": s.gyro[:, 1], "gz": s.gyro[:, 2]}
    if extra:
        mag = np.full((n, 3), np.nan)
        mag[::2] = np.array([0.2, -0.1, 0.4]) + np.arange(0, n, 2)[:, None] * 1e-4
        temp = 25.0 + np.arange(n) * 1e-3
        cols |= {"Magnetometer X (uT)": mag[:, 0], "Magnetometer Y (uT)": mag[:, 1],
                 "Magnetometer Z (uT)": mag[:, 2], "temp": temp, "a2x": s.acc[:, 0] * 1.01,
                 "a2y": s.acc[:, 1], "a2z": s.acc[:, 2]}
    path = tmp_path / ("extra.csv" if extra else "plain.csv")
    header = ",".join(cols)
    rows = np.column_stack(list(cols.values()))
    np.savetxt(path, rows, delimiter=",", header=header, comments="", fmt="%.17g")
    return path, s


def test_a_tables_other_streams_are_found_by_name(tmp_path):
    path, s = _table(tmp_path, extra=True)
    sess = load_session(path)
    others = {o.kind + " " + o.instance: o for o in sess.others}
    assert sorted(others) == ["acc a2", "mag m", "temp temp"]
    mag = others["mag m"]
    assert mag.unit == "uT" and mag.samples == (len(s.t_acc) + 1) // 2
    np.testing.assert_array_equal(mag.t, s.t_acc[::2])
    np.testing.assert_allclose(mag.values[1], [0.2002, -0.0998, 0.4002], rtol=1e-12)
    temp = others["temp temp"]
    assert temp.unit == "degC"
    assert temp.values[-1, 0] == pytest.approx(25.0 + (len(s.t_acc) - 1) * 1e-3)
    np.testing.assert_allclose(others["acc a2"].values[:, 0], s.acc[:, 0] * 1.01, rtol=1e-15)
    assert not any("ignored columns" in n for n in sess.notes)


def test_other_streams_leave_the_calibration_unchanged(tmp_path):
    out = []
    for extra in (False, True):
        path, _ = _table(tmp_path, extra)
        cal = tmp_path / f"cal{extra}.json"
        assert main(["calibrate", str(path), "--out", str(cal)]) == 0
        out.append(json.loads(cal.read_text()))
    assert out[0]["segments"] == out[1]["segments"]
    assert out[0]["quality"] == out[1]["quality"]


def test_inspect_lists_streams_and_what_is_taken(tmp_path, capsys):
    path, s = _table(tmp_path, extra=True)
    assert main(["inspect", str(path), "--json"]) == 0
    got = json.loads(capsys.readouterr().out)[0]
    rows = {(x["kind"], x["name"]): x for x in got["streams"]}
    assert rows[("acc", "accelerometer")]["picked"] and rows[("mag", "m")]["picked"]
    assert not rows[("temp", "temp")]["picked"] and not rows[("acc", "a2")]["picked"]
    assert rows[("acc", "accelerometer")]["samples"] == len(s.t_acc)
    assert rows[("gyro", "gyroscope")]["rate_hz"] == pytest.approx(1 / np.median(np.diff(s.t_gyro)))
    assert rows[("mag", "m")]["first"] == pytest.approx([0.2, -0.1, 0.4])
    missing = tmp_path / "missing.bag"
    assert main(["inspect", str(path), str(missing)]) == 1
    text = capsys.readouterr().out.splitlines()
    assert text[0] == "extra.csv (table): 5 streams"
    assert text[-1] == f"missing.bag: file not found (looked at {missing})"


def test_acc_selector_on_a_table_is_refused(tmp_path, capsys):
    path, _ = _table(tmp_path, extra=False)
    assert main(["calibrate", str(path), "--acc", "/imu", "--out",
                 str(tmp_path / "c.json")]) == 1
    err = capsys.readouterr().err.strip()
    assert err.endswith("--acc: --acc /imu names a stream of a log (a ROS bag, a ULog, a "
                        "DataFlash log); this file is a table: map its columns with --columns")
    assert not (tmp_path / "c.json").exists()
