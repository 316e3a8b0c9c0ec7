"""Real logger files, out of the box (issue 9): a metadata preamble above the table, a last line
cut by a killed logger, the column names real loggers write, a sample counter used as time.

Each test asserts on the numbers loaded (rate, shapes, values) and on the exact words a user
reads; each failed on the loader before these shapes were taught to it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import imucal
from imucal.errors import ImucalError
from imucal.io.export import write_session_csv
from imucal.io.load import load_session
from imucal.synth import make_session

IMUCAL = str(Path(sys.executable).with_name("imucal"))


@pytest.fixture(scope="module")
def synthetic():
    """A short synthetic session at 200 Hz: 12 poses, 30 s still at the start."""
    session, truth = make_session(poses=12, seed=5, acc_rate=200.0, init_still=30.0)
    return session, truth


def _rows(matrix: np.ndarray) -> str:
    return "".join(",".join(repr(float(v)) for v in row) + "\n" for row in matrix)


def _signals(n: int = 400, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    acc = rng.normal(size=(n, 3))
    acc /= np.linalg.norm(acc, axis=1, keepdims=True)
    return acc + rng.normal(scale=0.01, size=(n, 3)), rng.normal(scale=0.5, size=(n, 3))


# --- 1. a key,value preamble above the table ------------------------------------------------


def test_preamble_states_the_rate_and_the_initial_still_period(tmp_path, synthetic):
    session, _ = synthetic
    path = tmp_path / "logger.csv"
    write_session_csv(path, session, preamble={"sample_rate_hz": 200, "init_still_s": 30})
    s = load_session(path)
    assert s.acc.shape == s.gyro.shape == session.acc.shape
    assert np.array_equal(s.acc, session.acc) and np.array_equal(s.gyro, session.gyro)
    assert np.array_equal(s.t_acc, np.arange(len(s.acc)) / 200.0)
    assert s.acc_rate == pytest.approx(200.0) and s.init_still_s == 30.0
    assert ("logger.csv: its preamble states sample rate 200 Hz from 'sample_rate_hz' (line 1); "
            "initial still period 30 s from 'init_still_s' (line 2)") in s.notes
    assert "timestamps from the rate 200 Hz stated by logger.csv, 'sample_rate_hz' (line 1)" \
        in s.notes


def test_the_issue_example_with_a_device_line(tmp_path):
    acc, gyro = _signals()
    path = tmp_path / "xyz.csv"
    path.write_text("device,XYZ-IMU v2\nsample_rate_hz,200\ninit_still_s,30\n"
                    "time,ax,ay,az,gx,gy,gz\n" + _rows(np.hstack([np.arange(400)[:, None] / 200,
                                                                  acc, gyro])))
    s = load_session(path)
    assert s.acc.shape == (400, 3) and np.array_equal(s.acc, acc) and np.array_equal(s.gyro, gyro)
    assert s.t_acc[-1] == 399 / 200 and s.init_still_s == 30.0
    # the time column is used; it agrees with the stated rate, so no more is said of it
    assert not any("steps at" in n for n in s.notes)


@pytest.mark.parametrize("preamble, rate", [
    ("# Update Rate: 100.0Hz\n# Filter Profile: general\n", 100.0),   # Xsens MT Manager style
    ("Sample rate (Hz);250\nsensor;BMI160\n", 250.0),
    ("fs = 1 kHz\n", 1000.0),
    ("sample_period_ms: 5\n", 200.0),
])
def test_rate_spellings(tmp_path, preamble, rate):
    acc, gyro = _signals()
    path = tmp_path / "r.csv"
    path.write_text(preamble + "ax,ay,az,gx,gy,gz\n" + _rows(np.hstack([acc, gyro])))
    s = load_session(path)
    assert np.array_equal(s.t_acc, np.arange(400) / rate)
    assert np.array_equal(s.acc, acc)


def test_a_time_column_wins_over_a_stated_rate_and_a_disagreement_is_a_note(tmp_path):
    acc, gyro = _signals()
    t = np.arange(400) / 195.0
    path = tmp_path / "t.csv"
    path.write_text("rate,200\nt,ax,ay,az,gx,gy,gz\n" + _rows(np.hstack([t[:, None], acc, gyro])))
    s = load_session(path)
    assert np.array_equal(s.t_acc, t)
    assert ("t.csv states 200 Hz ('rate' (line 1)) but its column 't' steps at 195 Hz; the time "
            "column is used") in s.notes


def test_the_given_rate_wins_over_the_stated_one(tmp_path):
    acc, gyro = _signals()
    path = tmp_path / "g.csv"
    path.write_text("odr,200\nax,ay,az,gx,gy,gz\n" + _rows(np.hstack([acc, gyro])))
    s = load_session(path, rate=100)
    assert np.array_equal(s.t_acc, np.arange(400) / 100.0)
    assert "g.csv states 200 Hz ('odr' (line 1)) but --rate 100 was given; using 100 Hz" in s.notes


def test_a_two_column_table_is_no_preamble(tmp_path):
    path = tmp_path / "two.csv"
    path.write_text("t,x\n1,2\n3,4\n")
    with pytest.raises(ImucalError, match=r"two.csv: columns: no accelerometer columns found"):
        load_session(path)


def test_the_stated_initial_still_period_reaches_the_result_as_a_note(synthetic):
    session, _ = synthetic
    s = imucal.calibrate(imucal.Session(**{**session.__dict__, "init_still_s": 30.0}))
    note = [w for w in s.warnings if "initial still period" in w]
    assert len(note) == 1 and note[0].startswith("the file states an initial still period of "
                                                 "30 s; the first still block found spans 0.0-")


# --- 2. a last line cut by a logger killed mid-write ------------------------------------------


def test_a_cut_last_line_is_dropped_with_a_note(tmp_path, synthetic):
    session, _ = synthetic
    path = tmp_path / "killed.csv"
    write_session_csv(path, session, cut_last_line=True)
    n = len(session.acc)
    s = load_session(path)
    assert s.acc.shape == (n - 1, 3)
    assert np.array_equal(s.acc, session.acc[:-1]) and np.array_equal(s.t_acc, session.t_acc[:-1])
    fields = path.read_text().splitlines()[-1].count(",") + 1
    assert (f"killed.csv: dropped the last line (line {n + 1}): it has {fields} of 7 fields, as "
            "a logger stopped mid-write leaves it") in s.notes


def test_a_last_number_cut_short_is_dropped(tmp_path):
    acc, gyro = _signals()
    path = tmp_path / "num.txt"
    body = _rows(np.hstack([acc, gyro])).replace(",", " ")
    path.write_text(body + "0.5 0.1 0.8 0.01 0.02 1.5e-")
    s = load_session(path, rate=100)
    assert np.array_equal(s.acc, acc) and s.acc.shape == (400, 3)
    assert ("num.txt: dropped the last line (line 401): it ends in '1.5e-', a number cut short, "
            "as a logger stopped mid-write leaves it") in s.notes


def test_a_short_row_elsewhere_stays_an_error(tmp_path):
    acc, gyro = _signals()
    lines = _rows(np.hstack([acc, gyro])).splitlines()
    lines[100] = ",".join(lines[100].split(",")[:4])
    path = tmp_path / "ragged.csv"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ImucalError) as info:
        load_session(path, rate=100)
    assert str(info.value) == ("ragged.csv: ragged rows: line 101 has 4 fields, expected 6 "
                               "(1 ragged row in all)")


# --- 4. a sample counter used as time ---------------------------------------------------------


def test_a_counter_in_a_time_column_is_told_at_load(tmp_path):
    acc, gyro = _signals()
    path = tmp_path / "count.csv"
    path.write_text("time,ax,ay,az,gx,gy,gz\n" + _rows(np.hstack([np.arange(400)[:, None] + 7,
                                                                  acc, gyro])))
    with pytest.raises(ImucalError) as info:
        load_session(path)
    assert str(info.value) == (
        "count.csv: rate: column 'time' goes up in steps of 1 (7, 8, 9, ...): a sample counter, "
        "not seconds; give the sample rate with --rate HZ, or --time-unit ms (us, ns) if it "
        "counts milliseconds")
    s = load_session(path, rate=50)
    assert np.array_equal(s.t_acc, np.arange(400) / 50.0) and np.array_equal(s.acc, acc)
    s = load_session(path, time_unit="ms")  # or it counts milliseconds: 1 kHz
    assert np.array_equal(s.t_acc, (np.arange(400) + 7) * 1e-3)


def test_a_counter_mapped_as_time_is_told_at_load(tmp_path):
    acc, gyro = _signals()
    path = tmp_path / "ferraris_like.csv"
    path.write_text("n_samples,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z\n"
                    + _rows(np.hstack([np.arange(400)[:, None], gyro, acc])))
    with pytest.raises(ImucalError, match=r"column 'n_samples' goes up in steps of 1 \(0, 1, 2, "
                                          r"\.\.\.\): a sample counter, not seconds; give the "
                                          r"sample rate with --rate HZ, or --time-unit"):
        load_session(path, columns={"t": "n_samples"})


def test_cli_synth_shapes_load_and_calibrate(tmp_path):
    out = tmp_path / "pre.csv"
    proc = subprocess.run([IMUCAL, "synth", str(out), "--preamble", "--cut-last-line",
                           "--poses", "12", "--acc-rate", "200", "--init-still", "20"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    lines = out.read_text().splitlines()
    assert lines[:3] == ["sample_rate_hz,200", "init_still_s,20", "ax,ay,az,gx,gy,gz"]
    assert not out.read_text().endswith("\n")
    s = load_session(out)
    assert s.acc_rate == pytest.approx(200.0) and s.init_still_s == 20.0
    assert len(s.acc) == len(lines) - 4  # 3 preamble/header lines, and the cut one
    proc = subprocess.run([IMUCAL, "synth", str(tmp_path / "x.mat"), "--preamble"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "name OUT.csv" in proc.stderr
