"""A recording written as a table, a ROS 1 bag, a ROS 2 .db3 and an MCAP file calibrates to the
same calib.json numbers (issue 20): from a synthetic session and from a shared real recording."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from imucal.cli import main
from imucal.session import STANDARD_GRAVITY
from imucal.synth import make_session
from tests.io.bags import write_bag

SHARED = Path(__file__).resolve().parents[3] / "shared" / "data"
KEYS = ("ros1", "ros2", "mcap")


def _numbers(x, path=""):
    """Every number of a calib.json with where it sits, the file's own identity (its source and
    the loader's notes about it, among the warnings) left out."""
    if isinstance(x, dict):
        for k, v in x.items():
            if path == "" and k in ("source", "warnings"):
                continue
            yield from _numbers(v, f"{path}/{k}")
    elif isinstance(x, list):
        for i, v in enumerate(x):
            yield from _numbers(v, f"{path}/{i}")
    elif isinstance(x, bool) or x is None or isinstance(x, str):
        yield path, x
    else:
        yield path, float(x)


def _same(a: dict, b: dict) -> None:
    na, nb = dict(_numbers(a)), dict(_numbers(b))
    assert na.keys() == nb.keys()
    for k, va in na.items():
        vb = nb[k]
        if isinstance(va, float) and isinstance(vb, float):
            assert vb == pytest.approx(va, rel=1e-12, abs=1e-300), k
        elif isinstance(va, str) and isinstance(vb, str):
            continue  # messages may name the file
        else:
            assert va == vb, k


def _calibrate(path: Path, out: Path, *extra: str) -> dict:
    assert main(["calibrate", str(path), "--out", str(out), "--allow-poor", *extra]) == 0
    return json.loads(out.read_text())


def _table(path: Path, t: np.ndarray, acc: np.ndarray, gyro: np.ndarray) -> Path:
    header = "t,acc_x_ms2,acc_y_ms2,acc_z_ms2,gyr_x_rads,gyr_y_rads,gyr_z_rads"
    np.savetxt(path, np.column_stack([t, acc, gyro]), delimiter=",", header=header,
               comments="", fmt="%.17g")
    return path


def _bags_agree(tmp_path: Path, t: np.ndarray, acc: np.ndarray, gyro: np.ndarray,
                ref: dict) -> None:
    # stamps 1 s after the table's zero: the reader counts from the whole second before the
    # first stamp, so the bag's times are the table's
    for key in KEYS:
        bag = write_bag(tmp_path / key, key, acc, gyro, t + 1.0)
        got = _calibrate(bag, tmp_path / f"{key}.json")
        assert got["source"]["streams"][0].startswith("acc /imu/data_raw")
        _same(ref, got)


def test_a_synthetic_session_as_table_and_bags_calibrates_alike(tmp_path):
    s, _ = make_session(poses=16, seed=11, still=2.0, move=1.5)
    assert s.t_gyro is s.t_acc or np.array_equal(s.t_gyro, s.t_acc)
    acc = s.acc * STANDARD_GRAVITY
    ref = _calibrate(_table(tmp_path / "s.csv", s.t_acc, acc, s.gyro), tmp_path / "ref.json")
    _bags_agree(tmp_path, s.t_acc, acc, s.gyro, ref)


@pytest.mark.skipif(not (SHARED / "mikoff_mpu9150").is_dir(), reason="no shared recordings")
def test_a_real_recording_as_table_and_bags_calibrates_alike(tmp_path):
    data = np.loadtxt(SHARED / "mikoff_mpu9150" / "imu1.log")
    t = np.arange(len(data)) / 100.0
    ref = _calibrate(SHARED / "mikoff_mpu9150" / "imu1.log", tmp_path / "ref.json",
                     "--rate", "100")
    _bags_agree(tmp_path, t, data[:, :3], data[:, 3:6], ref)


def test_a_selector_that_matches_nothing_lists_the_topics(tmp_path, capsys):
    s, _ = make_session(poses=4, seed=1, still=1.0, move=1.0)
    bag = write_bag(tmp_path / "b", "ros1", s.acc * STANDARD_GRAVITY, s.gyro, s.t_acc + 1.0)
    out = tmp_path / "c.json"
    code = main(["calibrate", str(bag), "--acc", "/imu/nothere", "--gyro", "/imu/nothere",
                 "--out", str(out)])
    assert code == 1 and not out.exists()
    err = capsys.readouterr().err.strip()
    assert err.endswith("--acc: no accelerometer stream '/imu/nothere'; the file has: "
                        "/imu/data_raw (imucal inspect lists every stream)")
