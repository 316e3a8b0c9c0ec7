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
    note = [w.message for w in s.warnings if "initial still period" in w.message]
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


# --- 3. the column names real loggers write ----------------------------------------------------

G = 9.80665
# What each kind of column holds, from the accelerometer in g, the gyroscope in rad/s and the
# time in seconds: (source, scale). "junk" is a column to leave alone.
_UNITS = {"g": 1.0, "m/s^2": G, "mg": 1000.0, "rad/s": 1.0, "deg/s": np.rad2deg(1.0),
          "mdps": 1000 * np.rad2deg(1.0)}


def _logger_table(spec: list[tuple[str, str]], n: int = 400, t0: float = 0.0
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A table whose columns are described by (role, unit or time scale); returns it with the
    accelerometer (g), the gyroscope (rad/s) and the time (s) it holds."""
    acc, gyro = _signals(n)
    t = t0 + np.arange(n) / 100.0
    rng = np.random.default_rng(9)
    cols = []
    for role, unit in spec:
        if role == "t":
            cols.append(t / float(unit))
        elif role in ("ax", "ay", "az"):
            cols.append(acc[:, "xyz".index(role[1])] * _UNITS[unit])
        elif role in ("gx", "gy", "gz"):
            cols.append(gyro[:, "xyz".index(role[1])] * _UNITS[unit])
        elif role == "count":
            cols.append(np.arange(n) + 17.0)
        else:
            cols.append(rng.normal(size=n))
    return np.column_stack(cols), acc, gyro, t


LOGGERS = {
    "Arduino MPU-6050 sketch": (["millis", "AcX", "AcY", "AcZ", "Tmp", "GyX", "GyY", "GyZ"],
                                [("t", "1e-3"), ("ax", "g"), ("ay", "g"), ("az", "g"),
                                 ("junk", ""), ("gx", "deg/s"), ("gy", "deg/s"), ("gz", "deg/s")]),
    "x-io x-IMU3": (["Timestamp (us)", "Gyroscope X (deg/s)", "Gyroscope Y (deg/s)",
                     "Gyroscope Z (deg/s)", "Accelerometer X (g)", "Accelerometer Y (g)",
                     "Accelerometer Z (g)"],
                    [("t", "1e-6"), ("gx", "deg/s"), ("gy", "deg/s"), ("gz", "deg/s"),
                     ("ax", "g"), ("ay", "g"), ("az", "g")]),
    "Xsens MT Manager": (["PacketCounter", "SampleTimeFine", "Acc_X", "Acc_Y", "Acc_Z",
                          "FreeAcc_X", "FreeAcc_Y", "FreeAcc_Z", "Gyr_X", "Gyr_Y", "Gyr_Z"],
                         [("count", ""), ("t", "1e-4"), ("ax", "m/s^2"), ("ay", "m/s^2"),
                          ("az", "m/s^2"), ("junk", ""), ("junk", ""), ("junk", ""),
                          ("gx", "rad/s"), ("gy", "rad/s"), ("gz", "rad/s")]),
    "ROS rostopic -p": (["%time", "field.header.seq", "field.header.stamp",
                         "field.orientation.x", "field.angular_velocity.x",
                         "field.angular_velocity.y", "field.angular_velocity.z",
                         "field.linear_acceleration.x", "field.linear_acceleration.y",
                         "field.linear_acceleration.z", "field.linear_acceleration_covariance0"],
                        [("junk", ""), ("count", ""), ("t", "1e-9"), ("junk", ""),
                         ("gx", "rad/s"), ("gy", "rad/s"), ("gz", "rad/s"), ("ax", "m/s^2"),
                         ("ay", "m/s^2"), ("az", "m/s^2"), ("junk", "")]),
    "PlotJuggler": (["__time", "/imu/angular_velocity/x", "/imu/angular_velocity/y",
                     "/imu/angular_velocity/z", "/imu/linear_acceleration/x",
                     "/imu/linear_acceleration/y", "/imu/linear_acceleration/z",
                     "/imu/header/stamp"],
                    [("junk", ""), ("gx", "rad/s"), ("gy", "rad/s"), ("gz", "rad/s"),
                     ("ax", "m/s^2"), ("ay", "m/s^2"), ("az", "m/s^2"), ("t", "1")]),
    "AndroSensor": (["LINEAR ACCELERATION X (m/s²)", "LINEAR ACCELERATION Y (m/s²)",
                     "LINEAR ACCELERATION Z (m/s²)", "ACCELEROMETER X (m/s²)",
                     "ACCELEROMETER Y (m/s²)", "ACCELEROMETER Z (m/s²)", "GYROSCOPE X (rad/s)",
                     "GYROSCOPE Y (rad/s)", "GYROSCOPE Z (rad/s)", "Time since start in ms "],
                    [("junk", ""), ("junk", ""), ("junk", ""), ("ax", "m/s^2"),
                     ("ay", "m/s^2"), ("az", "m/s^2"), ("gx", "rad/s"), ("gy", "rad/s"),
                     ("gz", "rad/s"), ("t", "1e-3")]),
    "ST MEMS Studio": (["T [ms]", "A_X [mg]", "A_Y [mg]", "A_Z [mg]", "G_X [mdps]",
                        "G_Y [mdps]", "G_Z [mdps]"],
                       [("t", "1e-3"), ("ax", "mg"), ("ay", "mg"), ("az", "mg"),
                        ("gx", "mdps"), ("gy", "mdps"), ("gz", "mdps")]),
    "Bosch": (["timestamp_us", "accX", "accY", "accZ", "gyrX", "gyrY", "gyrZ"],
              [("t", "1e-6"), ("ax", "g"), ("ay", "g"), ("az", "g"), ("gx", "deg/s"),
               ("gy", "deg/s"), ("gz", "deg/s")]),
    "Physics Toolbox": (["time", "gFx", "gFy", "gFz", "wx", "wy", "wz"],
                        [("t", "1"), ("ax", "g"), ("ay", "g"), ("az", "g"), ("gx", "rad/s"),
                         ("gy", "rad/s"), ("gz", "rad/s")]),
}


@pytest.mark.parametrize("logger", LOGGERS)
def test_column_names_of_real_loggers(tmp_path, logger):
    names, spec = LOGGERS[logger]
    t0 = 1.7e9 if logger == "ROS rostopic -p" else 0.0
    matrix, acc, gyro, t = _logger_table(spec, t0=t0)
    path = tmp_path / "log.csv"
    path.write_text(",".join(names) + "\n" + _rows(matrix))
    s = load_session(path)
    assert s.acc.shape == s.gyro.shape == (400, 3)
    unit = next(u for r, u in spec if r == "ax")
    g = G if unit == "m/s^2" else 1.0
    assert s.acc_unit == ("m/s^2" if g != 1.0 else "g")
    np.testing.assert_allclose(s.acc, acc * g, rtol=1e-12)
    np.testing.assert_allclose(s.gyro, gyro, rtol=1e-12)
    np.testing.assert_allclose(s.t_acc, t, rtol=1e-12)
    assert s.acc_rate == pytest.approx(100.0, rel=1e-6)


def test_android_sensor_logger_two_files(tmp_path):
    """Sensor Logger writes one file per sensor: time (ns since the epoch), seconds_elapsed,
    then z, y, x; the seconds_elapsed column is the sample's time."""
    acc, gyro = _signals()
    t = np.arange(400) / 100.0
    paths = []
    for name, values in (("Accelerometer.csv", acc * G), ("Gyroscope.csv", gyro)):
        m = np.column_stack([1.7e18 + t * 1e9, t, values[:, ::-1]])
        (tmp_path / name).write_text("time,seconds_elapsed,z,y,x\n" + _rows(m))
        paths.append(tmp_path / name)
    s = load_session(paths[0], gyro_path=paths[1])
    np.testing.assert_allclose(s.acc, acc * G, rtol=1e-12)
    np.testing.assert_array_equal(s.gyro, gyro)
    np.testing.assert_array_equal(s.t_acc, t)


def test_phyphox_two_files(tmp_path):
    acc, gyro = _signals()
    t = np.arange(400) / 100.0
    a = tmp_path / "Accelerometer.csv"
    a.write_text('"Time (s)","Acceleration x (m/s^2)","Acceleration y (m/s^2)",'
                 '"Acceleration z (m/s^2)"\n' + _rows(np.column_stack([t, acc * G])))
    w = tmp_path / "Gyroscope.csv"
    w.write_text('"Time (s)","Gyroscope x (rad/s)","Gyroscope y (rad/s)","Gyroscope z (rad/s)"\n'
                 + _rows(np.column_stack([t, gyro])))
    s = load_session(a, gyro_path=w)
    assert s.acc_unit == "m/s^2" and s.gyro_unit == "rad/s"
    np.testing.assert_array_equal(s.acc, acc * G)
    np.testing.assert_array_equal(s.t_gyro, t)


def test_unnamed_columns_get_a_guess_ready_to_paste(tmp_path, synthetic):
    session, _ = synthetic
    m = np.hstack([session.t_acc[:, None], session.acc, session.gyro,
                   np.full((len(session.acc), 1), 25.0)])
    path = tmp_path / "opaque.csv"
    path.write_text("c0,c1,c2,c3,c4,c5,c6,temp\n" + _rows(m))
    with pytest.raises(ImucalError) as info:
        load_session(path)
    message = str(info.value)
    assert message.startswith("opaque.csv: columns: no accelerometer columns found (columns: c0, "
                              "c1, c2, c3, c4, c5, c6, temp); expected names like ax/acc_x, or "
                              "map them with --columns; by their values, c0 increases (time); "
                              "c1, c2, c3 look like the accelerometer (norm ")
    assert message.endswith("; c4, c5, c6 look like the gyroscope (quiet, with bursts): "
                            "--columns t=c0,ax=c1,ay=c2,az=c3,gx=c4,gy=c5,gz=c6")
    # pasted back, the guess loads the session
    from imucal.cli.options import parse_columns
    s = load_session(path, columns=parse_columns(message.split("--columns ")[-1]))
    assert np.array_equal(s.acc, session.acc) and np.array_equal(s.t_acc, session.t_acc)


def test_headerless_columns_get_positions_to_paste(tmp_path, synthetic):
    session, _ = synthetic
    m = np.hstack([session.gyro, session.t_acc[:, None], session.acc, session.acc[:, :2]])
    path = tmp_path / "nine.txt"
    path.write_text(_rows(m).replace(",", " "))
    with pytest.raises(ImucalError) as info:
        load_session(path)
    message = str(info.value)
    assert message.startswith("nine.txt: columns: found 9 column(s); expected 6 columns")
    assert message.endswith("--columns t=3,ax=4,ay=5,az=6,gx=0,gy=1,gz=2")


def test_two_equally_good_columns_name_the_option(tmp_path):
    path = tmp_path / "twice.csv"
    path.write_text("t,ax,ay,az,acc_x,gy,gz\n" + _rows(np.ones((5, 7))))
    with pytest.raises(ImucalError) as info:
        load_session(path)
    assert str(info.value) == ("twice.csv: columns: columns 'ax' and 'acc_x' both look like "
                               "'ax'; choose one with --columns ax=acc_x")


# --- 5. the loader in modules of one idea each ------------------------------------------------


def test_no_io_module_outgrows_one_idea():
    io_dir = Path(__file__).resolve().parents[1] / "imucal" / "io"
    sizes = {p.name: len(p.read_text().splitlines()) for p in io_dir.glob("*.py")}
    assert "load.py" in sizes and "column_names.py" in sizes and "time_base.py" in sizes
    assert {name: n for name, n in sizes.items() if n > 400} == {}
