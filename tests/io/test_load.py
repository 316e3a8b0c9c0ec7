"""imucal.io.load: every layout round-trips, the real recordings load, bad input explains itself."""

from __future__ import annotations

import hashlib
import zipfile
from pathlib import Path

import h5py
import numpy as np
import polars as pl
import pytest
import scipy.io
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from imucal.errors import ImucalError
from imucal.io.load import load_session

AXES6 = ["ax", "ay", "az", "gx", "gy", "gz"]


def make_signals(n: int = 300, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Accelerometer in g (unit vectors plus noise), gyroscope in rad/s, timestamps at 100 Hz."""
    rng = np.random.default_rng(seed)
    acc = rng.normal(size=(n, 3))
    acc /= np.linalg.norm(acc, axis=1, keepdims=True)
    acc += rng.normal(scale=0.01, size=(n, 3))
    gyro = rng.normal(scale=0.5, size=(n, 3))
    t = 12.5 + np.arange(n) / 100.0  # does not start at 0: the loader must keep the offset
    return acc, gyro, t


def assert_session(s, acc, gyro, t_acc, t_gyro=None, exact=True) -> None:
    check = np.testing.assert_array_equal if exact else np.testing.assert_allclose
    check(s.acc, acc)
    check(s.t_acc, t_acc)
    if gyro is None:
        assert s.gyro is None
    else:
        check(s.gyro, gyro)
        check(s.t_gyro, t_acc if t_gyro is None else t_gyro)
    for arr in (s.acc, s.t_acc, s.gyro, s.t_gyro):
        if arr is not None:
            assert arr.dtype == np.float64 and arr.flags.c_contiguous
    assert s.acc.shape == (len(acc), 3)


def write_csv(path: Path, names: list[str] | None, matrix: np.ndarray, sep: str = ",") -> Path:
    rows = [sep.join(repr(float(v)) for v in row) for row in matrix]
    header = [sep.join(names)] if names else []
    path.write_text("\n".join(header + rows) + "\n")
    return path


# --- MATLAB v5 -------------------------------------------------------------------------------


@pytest.mark.parametrize("transpose", [False, True], ids=["Nx6", "6xN"])
def test_mat5_one_matrix_without_time(tmp_path, transpose):
    acc, gyro, _ = make_signals()
    m = np.hstack([acc, gyro])
    path = tmp_path / "rec.mat"
    scipy.io.savemat(path, {"data": m.T if transpose else m})
    s = load_session(path, rate=100)
    assert_session(s, acc, gyro, np.arange(len(acc)) / 100.0, exact=False)
    assert s.source == "rec.mat"
    assert s.acc_unit == "g" and s.gyro_unit == "rad/s"


@pytest.mark.parametrize("transpose", [False, True], ids=["Nx7", "7xN"])
def test_mat5_one_matrix_with_time(tmp_path, transpose):
    acc, gyro, t = make_signals()
    m = np.hstack([t[:, None], acc, gyro])
    path = tmp_path / "rec.mat"
    scipy.io.savemat(path, {"M": m.T if transpose else m})
    assert_session(load_session(path), acc, gyro, t)


def test_mat5_named_variables_different_rates(tmp_path):
    acc, _, _ = make_signals(400, seed=1)
    _, gyro, _ = make_signals(150, seed=2)
    t_acc = 3.0 + np.arange(400) / 200.0
    t_gyro = 3.0 + np.arange(150) / 75.0
    path = tmp_path / "named.mat"
    scipy.io.savemat(path, {"Acc": acc.T, "gyro": gyro, "t_acc": t_acc, "t_gyro": t_gyro[:, None],
                            "label": "session 1"})
    s = load_session(path)
    assert_session(s, acc, gyro, t_acc, t_gyro)
    assert s.acc_rate == pytest.approx(200.0) and s.gyro_rate == pytest.approx(75.0)


def test_mat5_named_variables_with_time_column_and_shared_time(tmp_path):
    acc, gyro, t = make_signals()
    path = tmp_path / "named.mat"
    scipy.io.savemat(path, {"accelerometer": np.hstack([t[:, None], acc]), "omega": gyro.T,
                            "time": t})
    assert_session(load_session(path), acc, gyro, t)


def test_mat5_accelerometer_only_variable(tmp_path):
    acc, _, t = make_signals()
    path = tmp_path / "acc_only.mat"
    scipy.io.savemat(path, {"a": acc, "t": t})
    with pytest.raises(ImucalError, match="no gyroscope.*--acc-only"):
        load_session(path)
    s = load_session(path, acc_only=True)
    assert_session(s, acc, None, t)
    assert any("accelerometer only" in n for n in s.notes)


# --- MATLAB v7.3 (HDF5) ----------------------------------------------------------------------


def write_v73(path: Path, variables: dict[str, np.ndarray], userblock: bool) -> Path:
    """Write as MATLAB does: column-major, so h5py sees the transpose; text header in a
    512-byte user block when ``userblock``."""
    with h5py.File(path, "w", userblock_size=512 if userblock else 0) as f:
        for name, value in variables.items():
            if isinstance(value, str):
                ds = f.create_dataset(name, data=np.frombuffer(value.encode(), np.uint8)[:, None])
                ds.attrs["MATLAB_class"] = np.bytes_("char")
                continue
            ds = f.create_dataset(name, data=np.atleast_2d(value).T)
            ds.attrs["MATLAB_class"] = np.bytes_("double")
    if userblock:
        header = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan  1 00:00:00 2024"
        header += b" HDF5 schema 1.00 ."
        with path.open("r+b") as fh:
            fh.write(header.ljust(116) + b"\x00" * 8 + b"\x00\x02IM")
    return path


def test_hdf5_one_matrix_at_offset_0(tmp_path):
    acc, gyro, t = make_signals()
    path = write_v73(tmp_path / "v73.mat", {"data": np.hstack([t[:, None], acc, gyro])}, False)
    assert path.read_bytes()[:8] == b"\x89HDF\r\n\x1a\n"
    assert_session(load_session(path), acc, gyro, t)


def test_hdf5_matlab_userblock_named_variables(tmp_path):
    acc, gyro, t = make_signals()
    path = write_v73(tmp_path / "v73.mat", {"acc": acc, "gyro": gyro.T, "t": t[None, :],
                                            "who": "me"}, True)
    raw = path.read_bytes()
    assert raw.startswith(b"MATLAB 7.3 MAT-file") and raw[512:520] == b"\x89HDF\r\n\x1a\n"
    assert_session(load_session(path), acc, gyro, t)


# --- tables ----------------------------------------------------------------------------------

SPELLINGS = {
    "short": ["t", "ax", "ay", "az", "gx", "gy", "gz"],
    "snake": ["time", "acc_x", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z"],
    "phyphox": ["Time (s)", "Acceleration x (g)", "Acceleration y (g)", "Acceleration z (g)",
                "Gyroscope x (rad/s)", "Gyroscope y (rad/s)", "Gyroscope z (rad/s)"],
    "suffix": ["timestamp", "x_acc", "y_acc", "z_acc", "x_gyro", "y_gyro", "z_gyro"],
    "ros": ["time_s", "linear_acceleration_x", "linear_acceleration_y", "linear_acceleration_z",
            "angular_velocity_x", "angular_velocity_y", "angular_velocity_z"],
    "camel": ["Timestamp", "AccX", "AccY", "AccZ", "OmegaX", "OmegaY", "OmegaZ"],
    "units": ["t_s", "acc_x_g", "acc_y_g", "acc_z_g", "w_x", "w_y", "w_z"],
}


@pytest.mark.parametrize("style", SPELLINGS)
def test_csv_header_spellings(tmp_path, style):
    acc, gyro, t = make_signals()
    names = SPELLINGS[style]
    # Shuffle the columns and add unrelated ones: mapping goes by name, not position.
    order = [3, 0, 6, 1, 4, 2, 5]
    matrix = np.hstack([t[:, None], acc, gyro, np.full((len(t), 1), 25.0)])
    path = write_csv(tmp_path / "rec.csv", [names[i] for i in order] + ["temperature"],
                     matrix[:, order + [7]])
    s = load_session(path)
    assert_session(s, acc, gyro, t)
    assert any("temperature" in n for n in s.notes)


def test_csv_headerless_six_and_seven_columns(tmp_path):
    acc, gyro, t = make_signals()
    six = write_csv(tmp_path / "six.csv", None, np.hstack([acc, gyro]))
    assert_session(load_session(six, rate=100), acc, gyro, np.arange(len(t)) / 100.0)
    seven = write_csv(tmp_path / "seven.txt", None, np.hstack([t[:, None], acc, gyro]))
    assert_session(load_session(seven), acc, gyro, t)


def test_tsv_and_semicolon_decimal_comma(tmp_path):
    acc, gyro, t = make_signals()
    m = np.hstack([t[:, None], acc, gyro])
    tsv = write_csv(tmp_path / "rec.tsv", ["t", *AXES6], m, sep="\t")
    assert_session(load_session(tsv), acc, gyro, t)
    rows = [";".join(f"{v:.6f}".replace(".", ",") for v in row) for row in m]
    euro = tmp_path / "euro.csv"
    euro.write_text("\n".join([";".join(["t", *AXES6]), *rows]) + "\n")
    s = load_session(euro)
    np.testing.assert_allclose(s.acc, acc, atol=1e-6)
    np.testing.assert_allclose(s.t_acc, t, atol=1e-6)


@pytest.mark.parametrize("fmt", ["%15.7e", "%g"], ids=["aligned", "ragged-widths"])
def test_whitespace_text_with_leading_spaces(tmp_path, fmt):
    acc, gyro, t = make_signals()
    path = tmp_path / "ws.mat"  # text despite the extension, like imu_tk's files
    np.savetxt(path, np.hstack([t[:, None], acc, gyro]), fmt=fmt, delimiter="   ")
    text = path.read_text().splitlines()
    path.write_text("\n".join("  " + line for line in text) + "\n\n")  # leading spaces, blank end
    expected = np.loadtxt(path)
    assert_session(load_session(path), expected[:, 1:4], expected[:, 4:], expected[:, 0])


def test_whitespace_text_with_header_and_commented_header(tmp_path):
    acc, gyro, t = make_signals()
    m = np.hstack([t[:, None], acc, gyro])
    path = tmp_path / "hdr.txt"
    np.savetxt(path, m, fmt="%.17g", header=" ".join(["t", *AXES6]))  # "# t ax ..."
    assert path.read_text().startswith("# t ax")
    assert_session(load_session(path), acc, gyro, t)
    path2 = tmp_path / "hdr2.txt"
    np.savetxt(path2, m, fmt="%.17g", header=" ".join(["t", *AXES6]), comments="")
    assert_session(load_session(path2), acc, gyro, t)


def test_parquet(tmp_path):
    acc, gyro, t = make_signals()
    frame = pl.DataFrame({"timestamp": t, **{f"acc_{a}": acc[:, i] for i, a in enumerate("xyz")},
                          **{f"gyro_{a}": gyro[:, i] for i, a in enumerate("xyz")},
                          "note": ["x"] * len(t)})
    path = tmp_path / "rec.csv"  # the extension lies; the magic bytes decide
    frame.write_parquet(path)
    assert_session(load_session(path), acc, gyro, t)


def test_parquet_datetime_time_column(tmp_path):
    acc, gyro, _ = make_signals(50)
    stamps = pl.datetime_range(pl.datetime(2024, 1, 1), pl.datetime(2024, 1, 1, 0, 0, 0, 490000),
                               interval="10ms", eager=True)
    signals = dict(zip(AXES6, np.hstack([acc, gyro]).T, strict=True))
    frame = pl.DataFrame({"time": stamps, **signals})
    path = tmp_path / "dt.parquet"
    frame.write_parquet(path)
    s = load_session(path, time_unit="ms")  # date-times are already absolute: time_unit unused
    assert s.acc_rate == pytest.approx(100.0)
    assert s.t_acc[0] == pytest.approx(1704067200.0)


def test_two_file_text_session(tmp_path):
    acc, _, t_acc = make_signals(300, seed=3)
    _, gyro, _ = make_signals(200, seed=4)
    t_gyro = 12.5 + np.arange(200) / 66.0
    pa = write_csv(tmp_path / "acc.txt", None, np.hstack([t_acc[:, None], acc]), sep=" ")
    pg = write_csv(tmp_path / "gyro.txt", ["time", "x", "y", "z"],
                   np.hstack([t_gyro[:, None], gyro]))
    s = load_session(pa, gyro_path=pg)
    assert_session(s, acc, gyro, t_acc, t_gyro)
    assert s.source == "acc.txt + gyro.txt"
    both = pa.read_bytes() + pg.read_bytes()
    assert s.sha256 == hashlib.sha256(both).hexdigest()


def test_two_file_session_with_rate(tmp_path):
    acc, gyro, _ = make_signals()
    pa = write_csv(tmp_path / "a.csv", None, acc)
    pg = write_csv(tmp_path / "g.csv", None, gyro)
    s = load_session(pa, gyro_path=pg, rate=50)
    assert_session(s, acc, gyro, np.arange(len(acc)) / 50.0)


def test_two_file_session_with_columns(tmp_path):
    """The same column names in both files: each file takes only its own roles."""
    acc, gyro, t = make_signals()
    pa = write_csv(tmp_path / "a.csv", ["clock", "X", "Y", "Z"], np.hstack([t[:, None], acc]))
    pg = write_csv(tmp_path / "g.csv", ["clock", "X", "Y", "Z"], np.hstack([t[:, None], gyro]))
    columns = {"t": "clock", "ax": "X", "ay": "Y", "az": "Z", "gx": "X", "gy": "Y", "gz": "Z"}
    assert_session(load_session(pa, gyro_path=pg, columns=columns), acc, gyro, t)


def test_sha256_of_single_file(tmp_path):
    acc, gyro, t = make_signals()
    path = write_csv(tmp_path / "rec.csv", ["t", *AXES6], np.hstack([t[:, None], acc, gyro]))
    assert load_session(path).sha256 == hashlib.sha256(path.read_bytes()).hexdigest()


def test_explicit_columns_by_name_and_position(tmp_path):
    acc, gyro, t = make_signals()
    m = np.hstack([t[:, None], acc, gyro])
    names = ["clock", "c1", "c2", "c3", "c4", "c5", "c6"]
    path = write_csv(tmp_path / "odd.csv", names, m)
    mapping = dict(zip(["t", *AXES6], names, strict=True))
    assert_session(load_session(path, columns=mapping), acc, gyro, t)
    bare = write_csv(tmp_path / "bare.csv", None, m[:, [0, 4, 5, 6, 1, 2, 3]])
    positions = {"t": 0, "gx": 1, "gy": 2, "gz": 3, "ax": 4, "ay": 5, "az": 6}
    assert_session(load_session(bare, columns=positions), acc, gyro, t)


def test_counter_column_is_not_time(tmp_path):
    acc, gyro, _ = make_signals()
    counter = np.arange(len(acc), dtype=float)
    named = write_csv(tmp_path / "named.csv", ["n_samples", *AXES6],
                      np.hstack([counter[:, None], acc, gyro]))
    with pytest.raises(ImucalError, match="rate"):
        load_session(named)
    assert_session(load_session(named, rate=200), acc, gyro, counter / 200)
    bare = write_csv(tmp_path / "bare.csv", None, np.hstack([counter[:, None], acc, gyro]))
    with pytest.raises(ImucalError, match="counter"):
        load_session(bare)
    assert_session(load_session(bare, rate=200), acc, gyro, counter / 200)


def test_time_units(tmp_path):
    acc, gyro, t = make_signals()
    m = np.hstack([t[:, None] * 1000, acc, gyro])
    path = write_csv(tmp_path / "ms.csv", ["t", *AXES6], m)
    assert_session(load_session(path, time_unit="ms"), acc, gyro, m[:, 0] * 1e-3)
    named = write_csv(tmp_path / "named_ms.csv", ["time_ms", *AXES6], m)
    s = load_session(named)  # the name says ms
    np.testing.assert_allclose(s.t_acc, t)
    ns = np.hstack([np.round(t[:, None] * 1e9), acc, gyro])
    s = load_session(write_csv(tmp_path / "ns.csv", ["t", *AXES6], ns), time_unit="ns")
    np.testing.assert_allclose(s.t_acc, t, rtol=0, atol=1e-9)


def test_unnamed_integer_timestamps_in_ms_or_ns(tmp_path):
    """Loggers write integer ms or ns (often since boot) under names that say no unit; as
    seconds they would mean one sample in days. The unit whose step gives an IMU's rate is
    used, and said."""
    acc, gyro, t = make_signals()
    for unit, scale, offset in (("ms", 1e3, 5_000_123), ("ns", 1e9, 123_456_789_012_345)):
        stamps = np.round(t * scale) + offset
        path = write_csv(tmp_path / f"{unit}.csv", ["timestamp", *AXES6],
                         np.hstack([stamps[:, None], acc, gyro]))
        s = load_session(path)
        assert s.acc_rate == pytest.approx(100.0)
        np.testing.assert_allclose(s.t_acc - s.t_acc[0], t - t[0], atol=1e-9)
        assert any(f"read in {unit}" in n for n in s.notes), s.notes
    # seconds stay seconds, and an explicit unit is obeyed
    plain = write_csv(tmp_path / "s.csv", ["timestamp", *AXES6], np.hstack([t[:, None], acc, gyro]))
    assert not any("read in" in n for n in load_session(plain).notes)


def test_datetime_strings_in_text(tmp_path):
    acc, gyro, t = make_signals(50)
    import datetime

    start = datetime.datetime(2024, 5, 1, 12, 0, 0)
    for fmt, suffix in (("%Y-%m-%d %H:%M:%S.%f", ""), ("%Y-%m-%dT%H:%M:%S.%f", "Z")):
        stamps = [(start + datetime.timedelta(seconds=float(ti))).strftime(fmt) + suffix
                  for ti in t]
        rows = [",".join([stamp, *(repr(float(v)) for v in row)])
                for stamp, row in zip(stamps, np.hstack([acc, gyro]))]
        path = _text(tmp_path / "dt.csv", "time," + ",".join(AXES6) + "\n" + "\n".join(rows) + "\n")
        s = load_session(path)
        np.testing.assert_allclose(s.t_acc - s.t_acc[0], t - t[0], atol=2e-6)
        assert s.t_acc[0] == pytest.approx(1714564800.0 + t[0], abs=1e-3)
        np.testing.assert_array_equal(s.acc, acc)
    rows[7] = "yesterday" + rows[7][rows[7].index(","):]
    path = _text(tmp_path / "bad.csv", "time," + ",".join(AXES6) + "\n" + "\n".join(rows) + "\n")
    with pytest.raises(ImucalError, match=r"bad.csv: time: column 'time': 'yesterday' at line 9 "
                                          r"is not a date-time"):
        load_session(path)


def test_a_row_of_units_under_the_header(tmp_path):
    acc, gyro, t = make_signals()
    m = np.hstack([t[:, None], acc * 9.80665, np.rad2deg(gyro)])
    for units in ("s,m/s^2,m/s^2,m/s^2,deg/s,deg/s,deg/s", "[s],[m/s^2],[m/s^2],[m/s^2],[°/s],"
                  "[°/s],[°/s]"):
        rows = "\n".join(",".join(repr(float(v)) for v in row) for row in m)
        path = _text(tmp_path / "units.csv", "time,acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z\n"
                     + units + "\n" + rows + "\n")
        s = load_session(path)
        assert s.acc_unit == "m/s^2"
        np.testing.assert_allclose(s.gyro, gyro, rtol=1e-12)
        np.testing.assert_array_equal(s.t_acc, t)
    # a bad value is still reported on its own line of the file
    bad = rows.split("\n")
    bad[4] = bad[4].replace(bad[4].split(",")[2], "oops")
    path = _text(tmp_path / "bad.csv", "time,acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z\n" + units
                 + "\n" + "\n".join(bad) + "\n")
    with pytest.raises(ImucalError, match="'oops' at line 7"):
        load_session(path)


def test_two_sensors_on_rows_of_their_own(tmp_path):
    """Two logs merged on time: each row holds one sensor and leaves the other's cells empty
    (here the gyroscope at twice the accelerometer's rate)."""
    acc, _, t = make_signals(200)
    _, gyro, _ = make_signals(400, seed=1)
    t_g = np.arange(400) / 200.0
    lines = []
    for i, tg in enumerate(t_g):
        g = ",".join(repr(float(v)) for v in gyro[i])
        if i % 2 == 0:
            a = ",".join(repr(float(v)) for v in acc[i // 2])
            lines.append(f"{float(tg)!r},{a},,,")
        lines.append(f"{float(tg)!r},,,,{g}")
    path = _text(tmp_path / "merged.csv", "t," + ",".join(AXES6) + "\n" + "\n".join(lines) + "\n")
    s = load_session(path)
    assert_session(s, acc, gyro, t_g[::2], t_g)
    assert any("rows of their own" in n for n in s.notes)
    # a few rows without the accelerometer are dropouts, bridged as before
    m = np.hstack([t_g[::2, None], acc, gyro[::2]])
    rows = [",".join(repr(float(v)) for v in row) for row in m]
    rows[9] = repr(float(m[9, 0])) + ",,,," + ",".join(repr(float(v)) for v in m[9, 4:])
    s = load_session(_text(tmp_path / "few.csv", "t," + ",".join(AXES6) + "\n"
                           + "\n".join(rows) + "\n"))
    assert not any("rows of their own" in n for n in s.notes)
    assert any("bridged 1 NaN/Inf samples" in n for n in s.notes) and len(s.acc) == 200


def test_time_column_named_in_other_languages(tmp_path):
    acc, gyro, t = make_signals()
    for name in ("Zeit", "tiempo", "Temps"):
        path = write_csv(tmp_path / "lang.csv", [name, *AXES6], np.hstack([t[:, None], acc, gyro]),
                         sep=";")
        assert_session(load_session(path), acc, gyro, t)


def test_units_explicit_and_guessed(tmp_path):
    acc, gyro, t = make_signals()
    m = np.hstack([t[:, None], acc * 9.80665, np.rad2deg(gyro)])
    path = write_csv(tmp_path / "si.csv", ["t", *AXES6], m)
    s = load_session(path, gyro_unit="deg/s")
    assert s.acc_unit == "m/s^2" and s.gyro_unit == "rad/s"
    np.testing.assert_allclose(s.gyro, gyro)
    assert any("guessed as m/s^2" in n for n in s.notes)
    assert any("converted from deg/s" in n for n in s.notes)
    s = load_session(path, acc_unit="counts")
    assert s.acc_unit == "counts"
    named = write_csv(tmp_path / "named.csv", ["t", "acc_x_ms2", "acc_y_ms2", "acc_z_ms2",
                                               "gyr_x_dps", "gyr_y_dps", "gyr_z_dps"], m)
    s = load_session(named)
    assert s.acc_unit == "m/s^2" and s.gyro_unit == "rad/s"
    np.testing.assert_allclose(s.gyro, gyro)
    assert any("column names" in n for n in s.notes)


def test_accelerometer_only_file(tmp_path):
    acc, _, t = make_signals()
    path = write_csv(tmp_path / "acc.csv", None, np.hstack([t[:, None], acc]))
    with pytest.raises(ImucalError, match="acc.csv.*no gyroscope.*--gyro FILE"):
        load_session(path)
    s = load_session(path, acc_only=True)
    assert_session(s, acc, None, t)
    assert s.gyro_unit is None and not s.has_gyro
    assert "accelerometer only (--acc-only): acc.csv" in s.notes


def test_short_nan_runs_are_bridged_and_ends_dropped(tmp_path):
    acc, gyro, t = make_signals()
    m = np.hstack([t[:, None], acc, gyro])
    m[100:103, 2] = np.nan  # a dropped packet of 3 samples
    m[:2, 5] = np.inf  # junk at the start
    path = write_csv(tmp_path / "gaps.csv", ["t", *AXES6], m)
    s = load_session(path)
    assert np.isfinite(s.acc).all() and len(s.acc) == len(t)
    expected = acc[99] + (acc[103] - acc[99]) * (t[101] - t[99]) / (t[103] - t[99])
    np.testing.assert_allclose(s.acc[101], expected)
    assert len(s.gyro) == len(t) - 2 and s.t_gyro[0] == t[2]
    assert any("bridged 3" in n and "1 gap" in n and "100-102" in n for n in s.notes)
    assert any("dropped 2" in n and "start" in n for n in s.notes)


def test_empty_fields_are_missing_samples(tmp_path):
    acc, gyro, t = make_signals(20)
    m = np.hstack([t[:, None], acc, gyro])
    lines = ["t,ax,ay,az,gx,gy,gz"] + [",".join(repr(float(v)) for v in row) for row in m]
    parts = lines[5].split(",")
    parts[2] = ""
    lines[5] = ",".join(parts)
    path = tmp_path / "holes.csv"
    path.write_text("\r\n".join(lines) + "\r\n")
    s = load_session(path)
    assert np.isfinite(s.acc).all()
    assert any("bridged 1" in n for n in s.notes)


# --- the shared real recordings --------------------------------------------------------------


def test_real_imu_tk_xsens_two_files(shared_data):
    acc_path = shared_data / "imu_tk_xsens/xsens_acc.mat"
    gyro_path = shared_data / "imu_tk_xsens/xsens_gyro.mat"
    s = load_session(acc_path, gyro_path=gyro_path)  # its speed is measured in bench/run.py
    assert s.acc.shape == (51175, 3) and s.gyro.shape == (51175, 3)
    assert s.acc_unit == "counts" and s.gyro_unit == "counts"
    assert s.t_acc[0] == pytest.approx(0.02984) and s.t_acc[-1] == pytest.approx(511.718)
    assert s.acc[0].tolist() == [33108.0, 33329.0, 36429.0]
    assert s.source == "xsens_acc.mat + xsens_gyro.mat"


def test_real_mikoff_mpu9150(shared_data):
    s = load_session(shared_data / "mikoff_mpu9150/imu0.log", rate=100)
    assert s.acc_unit == "m/s^2" and s.gyro_unit == "rad/s"
    assert s.acc.shape == (15969, 3) and s.acc_rate == pytest.approx(100.0)
    np.testing.assert_allclose(s.acc[0], [-8.42090, 0.06710, 5.24511])
    np.testing.assert_allclose(s.gyro[0], [0.03515, 0.00213, 0.04155])


def test_real_imucal_ferraris(shared_data):
    path = shared_data / "imucal_ferraris/example_ferraris_session.csv"
    with pytest.raises(ImucalError, match="rate"):
        load_session(path)  # n_samples is a counter, not time
    s = load_session(path, rate=102.4)
    raw = pl.read_csv(path)
    assert s.acc_unit == "m/s^2" and s.gyro_unit == "rad/s"
    np.testing.assert_array_equal(s.acc, raw.select("acc_x", "acc_y", "acc_z").to_numpy())
    np.testing.assert_allclose(s.gyro, np.deg2rad(raw.select("gyr_x", "gyr_y", "gyr_z").to_numpy()))
    assert any("deg/s" in n for n in s.notes)


# --- errors ----------------------------------------------------------------------------------


def _table(n: int = 50, cols: int = 7) -> np.ndarray:
    acc, gyro, t = make_signals(n)
    return np.hstack([t[:, None], acc, gyro])[:, :cols]


def _text(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def _bad_time(kind: str):
    def write(p: Path) -> Path:
        m = _table()
        if kind == "decreasing":
            m[10, 0] = m[8, 0]
        elif kind == "duplicated":
            m[10, 0] = m[9, 0]
        else:
            m[10, 0] = np.nan
        return write_csv(p, ["t", *AXES6], m)

    return write


def _nan_run(p: Path) -> Path:
    m = _table()
    m[10:20, 1] = np.nan
    return write_csv(p, ["t", *AXES6], m)


def _zip(p: Path) -> Path:
    with zipfile.ZipFile(p, "w") as z:
        z.writestr("a.csv", "1,2,3\n")
    return p


def _mat(variables: dict):
    def write(p: Path) -> Path:
        scipy.io.savemat(p, variables)
        return p

    return write


def _corrupt(magic: bytes):
    def write(p: Path) -> Path:
        p.write_bytes(magic + b"\x00\x01garbage" * 50)
        return p

    return write


def _many_gaps(p: Path) -> Path:
    m = _table(200)
    m[10:200:10, 2] = np.nan  # 19 one-sample gaps: each short, together 9.5 %
    return write_csv(p, ["t", *AXES6], m)


def _huge(p: Path) -> Path:
    with p.open("wb") as fh:  # sparse: no disk space used
        fh.truncate(2 * 1024**3 + 1)
    return p


ERROR_CASES = {
    "empty": (lambda p: _text(p, ""), {}, "empty"),
    "blank": (lambda p: _text(p, "\n\n# only a comment\n"), {}, "no data"),
    "header only": (lambda p: _text(p, "t,ax,ay,az,gx,gy,gz\n"), {}, "no data"),
    "binary": (_corrupt(b"\x01\x02"), {}, "format"),
    "zip": (_zip, {}, "zip"),
    "text in numeric": (lambda p: _text(p, "t,ax,ay,az,gx,gy,gz\n0,1,0,0,0,0,0\n"
                                           "0.01,1,zero,0,0,0,0\n"), {}, "line 3"),
    "ragged": (lambda p: _text(p, "0 1 0 0 0 0 0\n0.01 1 0 0 0 0\n0.02 1 0 0 0 0 0\n"), {},
               "ragged"),
    "five columns": (lambda p: write_csv(p, None, _table(cols=5)), {}, "5 column"),
    "one sample": (lambda p: write_csv(p, ["t", *AXES6], _table(n=1)), {}, "at least 2"),
    "nan run": (_nan_run, {}, "NaN"),
    "decreasing time": (_bad_time("decreasing"), {}, "increasing"),
    "duplicated time": (_bad_time("duplicated"), {}, "duplicated"),
    "nan time": (_bad_time("nan"), {}, "timestamp"),
    "no rate": (lambda p: write_csv(p, None, _table()[:, 1:]), {}, "--rate"),
    "rate zero": (lambda p: write_csv(p, None, _table()[:, 1:]), {"rate": 0}, "rate"),
    "rate negative": (lambda p: write_csv(p, None, _table()[:, 1:]), {"rate": -5}, "rate"),
    "rate nan": (lambda p: write_csv(p, None, _table()[:, 1:]), {"rate": float("nan")}, "rate"),
    "rate huge": (lambda p: write_csv(p, None, _table()[:, 1:]), {"rate": 1e6}, "rate"),
    "unknown role": (lambda p: write_csv(p, ["t", *AXES6], _table()), {"columns": {"ux": "t"}},
                     "columns"),
    "missing column": (lambda p: write_csv(p, ["t", *AXES6], _table()),
                       {"columns": {"ax": "acc_x"}}, "no such column"),
    "unnamed columns": (lambda p: write_csv(p, list("abcdefg"), _table()), {}, "columns"),
    "ambiguous columns": (lambda p: write_csv(p, ["t", "ax", "ay", "az", "acc_x", "gy", "gz"],
                                              _table()), {}, "both look like"),
    "incomplete axes": (lambda p: write_csv(p, ["t", "ax", "ay", "q", "gx", "gy", "gz"],
                                            _table()), {}, "missing az"),
    "bad acc unit arg": (lambda p: write_csv(p, ["t", *AXES6], _table()), {"acc_unit": "furlong"},
                         "acc_unit"),
    "bad time unit arg": (lambda p: write_csv(p, ["t", *AXES6], _table()), {"time_unit": "min"},
                          "time_unit"),
    "unguessable unit": (lambda p: write_csv(p, ["t", *AXES6], _table() * [1, 3, 3, 3, 1, 1, 1]),
                         {}, "--acc-unit"),
    "mat no matrix": (_mat({"name": "hello"}), {}, "no numeric matrix"),
    "mat two matrices": (_mat({"p": np.ones((10, 6)), "q": np.ones((10, 6))}), {}, "several"),
    "mat bad shape": (_mat({"acc": np.ones((10, 5)), "gyro": np.ones((10, 3))}), {}, "shape"),
    "mat corrupt": (_corrupt(b"MATLAB 5.0 MAT-file, corrupted".ljust(128)), {}, "corrupt"),
    "hdf5 corrupt": (_corrupt(b"\x89HDF\r\n\x1a\n"), {}, "cannot read"),
    "parquet corrupt": (_corrupt(b"PAR1"), {}, "cannot read"),
    "too large": (_huge, {}, "2 GiB"),
    "many short gaps": (_many_gaps, {}, "more than the 5%"),
    "header count": (lambda p: _text(p, "t ax ay az gx gy\n" + "0 1 0 0 0 0 0\n" * 3), {},
                     "header has 6"),
    "counter no rate": (lambda p: write_csv(p, None, np.hstack([np.arange(50.0)[:, None],
                                                                _table()[:, 1:]])), {}, "counter"),
    "mat time length": (_mat({"data": np.ones((20, 6)), "t": np.arange(19.0)}), {}, "19 values"),
    "mat columns arg": (_mat({"acc": np.ones((20, 3))}), {"columns": {"ax": "x"}}, "columns"),
    "headerless by name": (lambda p: write_csv(p, None, _table()), {"columns": {"ax": "x"}},
                           "position"),
}


@pytest.mark.parametrize("case", ERROR_CASES)
def test_errors_name_file_and_problem(tmp_path, case):
    write, kwargs, word = ERROR_CASES[case]
    path = write(tmp_path / "bad_input.dat")
    with pytest.raises(ImucalError) as info:
        load_session(path, **kwargs)
    message = str(info.value)
    assert "bad_input.dat" in message
    assert word.lower() in message.lower()
    assert "\n" not in message


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(ImucalError, match="nowhere.csv.*not found"):
        load_session(tmp_path / "nowhere.csv")
    with pytest.raises(ImucalError, match="directory"):
        load_session(tmp_path)


def test_polars_panic_is_an_imucal_error(tmp_path, monkeypatch):
    """polars reports some malformed input with PanicException, a BaseException, and is imported
    only by the readers that need it; its panic must still become one ImucalError line."""
    from polars.exceptions import PanicException

    import imucal.io.readers

    def panic(path):
        raise PanicException("called `Option::unwrap()` on a `None` value\nat src/lib.rs")

    monkeypatch.setattr(imucal.io.readers, "_read_parquet", panic)
    path = _corrupt(b"PAR1")(tmp_path / "panic.parquet")
    with pytest.raises(ImucalError, match=r"panic.parquet: cannot read the file: PanicException: "
                                          r"called `Option::unwrap\(\)` on a `None` value$"):
        load_session(path)


def test_gyro_path_needs_three_column_files(tmp_path):
    six = write_csv(tmp_path / "six.csv", None, _table()[:, 1:])
    three = write_csv(tmp_path / "three.csv", None, _table()[:, 1:4])
    with pytest.raises(ImucalError, match="six.csv.*3 columns"):
        load_session(six, gyro_path=three, rate=100)
    with pytest.raises(ImucalError, match="missing.csv.*not found"):
        load_session(three, gyro_path=tmp_path / "missing.csv", rate=100)


# --- property: any CSV gives a session or an ImucalError, never another exception ---------


@st.composite
def csv_files(draw):
    n_rows = draw(st.integers(0, 12))
    n_cols = draw(st.integers(1, 8))
    finite = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)
    special = st.sampled_from([float("nan"), float("inf"), -float("inf"), 0.0, 1.0, 9.81])
    value = st.one_of(finite, special)
    matrix = np.array(draw(st.lists(st.lists(value, min_size=n_cols, max_size=n_cols),
                                    min_size=n_rows, max_size=n_rows)), dtype=float)
    if n_rows and draw(st.booleans()):  # a time column in a random order
        matrix[:, 0] = draw(st.permutations(np.arange(n_rows, dtype=float) / 100))
    header = draw(st.sampled_from([None, ["t", *AXES6, "x"], [f"c{i}" for i in range(8)]]))
    rate = draw(st.sampled_from([None, 100.0]))
    return matrix, header[:n_cols] if header else None, rate


@pytest.mark.filterwarnings("error")  # numpy warnings mean an unguarded operation
@settings(max_examples=60, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(csv_files())
def test_property_any_csv_loads_or_raises_imucal_error(tmp_path, case):
    matrix, header, rate = case
    path = tmp_path / "prop.csv"
    lines = [",".join(header)] if header else []
    lines += [",".join(repr(float(v)) for v in row) for row in matrix]
    path.write_text("\n".join(lines) + "\n")
    try:
        s = load_session(path, rate=rate)
    except ImucalError as err:
        assert "prop.csv" in str(err)
        return
    assert np.isfinite(s.acc).all() and np.all(np.diff(s.t_acc) > 0)
    assert s.acc.shape == (len(s.t_acc), 3)


def test_notes_say_each_thing_once(tmp_path):
    acc, gyro, t = make_signals()
    path = write_csv(tmp_path / "ms.csv", ["time_ms", *AXES6],
                     np.hstack([t[:, None] * 1000, acc, gyro]))
    notes = load_session(path).notes
    assert len(notes) == len(set(notes))
    assert sum("read in ms" in n for n in notes) == 1


def test_mat_time_variable_must_be_a_vector(tmp_path):
    acc, gyro, _ = make_signals()
    path = tmp_path / "tm.mat"
    scipy.io.savemat(path, {"acc": acc, "gyro": gyro, "t_acc": np.ones((300, 2))})
    with pytest.raises(ImucalError, match="tm.mat.*'t_acc'.*vector"):
        load_session(path)


def test_compressed_mat_reads_as_scipy_reads_it(tmp_path):
    """The structural check inflates each compressed variable once and hands scipy the
    inflated file: the values must be exactly those scipy reads from the compressed one."""
    import scipy.io

    rng = np.random.default_rng(3)
    acc = rng.normal(0, 0.01, (500, 3)) + [0, 0, 1]
    gyro = rng.normal(0, 0.01, (500, 3))
    t = np.arange(500) / 100.0
    path = tmp_path / "z.mat"
    scipy.io.savemat(path, {"acc": acc, "gyro": gyro, "t": t, "note": "text"},
                     do_compression=True)
    ref = scipy.io.loadmat(path)
    s = load_session(path)
    assert np.array_equal(s.acc, ref["acc"]) and np.array_equal(s.gyro, ref["gyro"])
    assert np.array_equal(s.t_acc, ref["t"].ravel())
