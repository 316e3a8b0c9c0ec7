"""HDF5 and MATLAB v7.3 files: the same recording as MAT v5, v7.3 and plain HDF5 calibrates
identically; files of one dataset per sensor (BROAD's imu_acc/imu_gyr/imu_mag) are read as
streams, checked against h5py's own reading."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import h5py
import numpy as np
import pytest
from scipy.io import loadmat

from imucal.cli import main
from imucal.errors import ImucalError
from imucal.io.load import load_session
from imucal.io.logs import log_format, read_log

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "sample_data" / "session.mat"
BROAD = ROOT.parent / "shared" / "data" / "broad"


def _write_v73(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """A MATLAB v7.3 file as MATLAB writes it: a 512-byte text header, then HDF5 with each
    matrix stored column-major (so h5py sees it transposed) and its MATLAB_class."""
    with h5py.File(path, "w", userblock_size=512) as f:
        for name, a in arrays.items():
            d = f.create_dataset(name, data=np.asarray(a).T)
            d.attrs["MATLAB_class"] = np.bytes_(b"double")
    with path.open("r+b") as fh:
        fh.write(b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: test HDF5 schema 1.00 .")


def _calibrate(path: Path, tmp_path: Path) -> dict:
    out = tmp_path / f"{path.stem}.json"
    assert main(["calibrate", str(path), "--out", str(out)]) == 0
    data = json.loads(out.read_text())
    data.pop("source")  # the file's name and hash: all else must agree
    return data


def test_mat5_v73_and_hdf5_calibrate_identically(tmp_path):
    arrays = {k: v for k, v in loadmat(SAMPLE).items() if not k.startswith("__")}
    v73 = tmp_path / "v73.mat"
    _write_v73(v73, arrays)
    plain = tmp_path / "plain.h5"
    with h5py.File(plain, "w") as f:
        for name, a in arrays.items():
            f.create_dataset(name, data=a)
    assert log_format(v73) is None and log_format(plain) is None  # the table loader's layout
    ref = _calibrate(SAMPLE, tmp_path)
    assert _calibrate(v73, tmp_path) == ref
    assert _calibrate(plain, tmp_path) == ref


def test_datasets_named_by_sensor_are_streams(tmp_path):
    n = 500
    rng = np.random.default_rng(1)
    acc, gyr, mag = rng.normal(size=(3, n, 3))
    path = tmp_path / "dev.h5"
    with h5py.File(path, "w") as f:
        g = f.create_group("imu0")
        g.create_dataset("accel", data=acc).attrs["units"] = "m/s^2"
        g.create_dataset("gyro_rates", data=gyr.T)  # 3 x N: samples along the longer side
        g.create_dataset("t", data=np.arange(n) * 0.005 + 2.0)
        f.create_dataset("compassBuffer", data=np.column_stack([np.arange(n) / 75.0, mag]))
        f.create_dataset("quat", data=rng.normal(size=(n, 4)))  # names no sensor: left alone
    assert log_format(path) == "hdf5"
    streams = {s.name: s for s in read_log(path, "hdf5", "dev.h5").streams}
    assert sorted(streams) == ["acc imu0/accel", "gyro imu0/gyro_rates", "mag compassBuffer"]
    a = streams["acc imu0/accel"]
    np.testing.assert_array_equal(a.values, acc)
    assert a.unit == "m/s^2" and a.imu == "imu0" and streams["gyro imu0/gyro_rates"].imu == (
        "imu0/rates")
    np.testing.assert_array_equal(streams["gyro imu0/gyro_rates"].values, gyr)
    np.testing.assert_array_equal(streams["gyro imu0/gyro_rates"].t, np.arange(n) * 0.005 + 2.0)
    np.testing.assert_allclose(streams["mag compassBuffer"].t, np.arange(n) / 75.0)
    sess = load_session(path, select={"gyro": "imu0/gyro_rates"})
    np.testing.assert_array_equal(sess.gyro, gyr)
    with pytest.raises(ImucalError, match=r"--acc: no accelerometer stream 'imu1/accel'"):
        load_session(path, select={"acc": "imu1/accel"})


def test_a_file_of_no_sensor_dataset_is_refused_in_one_line(tmp_path):
    path = tmp_path / "opt.h5"
    with h5py.File(path, "w") as f:
        f.create_dataset("opt_quat", data=np.zeros((10, 4)))
        f.create_dataset("opt_pos", data=np.zeros((10, 3)))
        f.create_dataset("imu_acc", data=np.zeros((10, 3)))  # has no time: left out, and said
    with pytest.raises(ImucalError) as info:
        load_session(path)
    assert str(info.value).startswith("opt.h5: datasets: no sensor dataset found (imu_acc, "
                                      "opt_pos, opt_quat)")


BROAD_FILES = {  # sha256, samples
    "02_undisturbed_slow_rotation_B.hdf5":
        ("33ed3432ece89cfbd8c5c069a176106a05dad019302759353244c71d70d7e5f5", 53240),
    "05_undisturbed_slow_rotation_with_breaks_B.hdf5":
        ("d74cc90958fc05a9fc1a6d58465a62c75a61f205a75ea2e6207ef37d7b1c89a7", 59212),
}


@pytest.mark.skipif(not BROAD.is_dir(), reason="the shared BROAD recordings are not here")
@pytest.mark.parametrize("name", sorted(BROAD_FILES))
def test_broad_trials_read_as_h5py_reads_them(name):
    path = BROAD / name
    streams = {s.kind: s for s in read_log(path, "hdf5", name).streams}
    with h5py.File(path, "r") as f:
        rate = float(f.attrs["sampling_rate"])
        for kind, ds, unit in (("acc", "imu_acc", "m/s^2"), ("gyro", "imu_gyr", "rad/s"),
                               ("mag", "imu_mag", "uT")):
            s = streams[kind]
            ref = f[ds][()]
            assert s.samples == BROAD_FILES[name][1] == len(ref)
            np.testing.assert_array_equal(s.values[[0, -1]], ref[[0, -1]])
            assert s.unit == unit
            assert s.rate == pytest.approx(rate, rel=1e-9)
    assert hashlib.sha256(path.read_bytes()).hexdigest() == BROAD_FILES[name][0]


@pytest.mark.skipif(not BROAD.is_dir(), reason="the shared BROAD recordings are not here")
def test_a_trial_with_three_still_breaks_is_refused_naming_what_is_missing(tmp_path, capsys):
    path = BROAD / "05_undisturbed_slow_rotation_with_breaks_B.hdf5"
    out = tmp_path / "c.json"
    assert main(["calibrate", str(path), "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert "1 distinct orientation" in err and not out.exists()


SUNSIDED = ROOT.parent / "shared" / "data" / "sunsided_mpu6050_hmc5883l" / "full-sphere"


@pytest.mark.skipif(not SUNSIDED.is_dir(), reason="the shared MPU6050/HMC5883L files are not here")
def test_a_v73_file_of_one_sensor_is_that_sensor(tmp_path):
    """A MATLAB v7.3 file per sensor: the magnetometer's compassBuffer (4 x N, time then x y z,
    gauss, on its own clock) is a magnetometer, not an accelerometer."""
    path = SUNSIDED / "hmc5883l_compass.mat"
    streams = read_log(path, log_format(path), path.name).streams
    assert [s.name for s in streams] == ["mag compassBuffer"]
    with h5py.File(path, "r") as f:
        ref = f["compassBuffer"][()].T  # MATLAB's column-major 4 x N
    mag = streams[0]
    assert mag.samples == len(ref) == 8190
    np.testing.assert_array_equal(mag.t, ref[:, 0])
    np.testing.assert_array_equal(mag.values[[0, -1]], ref[[0, -1], 1:])
    with pytest.raises(ImucalError, match="no accelerometer stream to calibrate"):
        load_session(path)
    # the two-file session of the same folder stays on the table loader's path
    sess = load_session(SUNSIDED / "mpu6050_accelerometer.mat",
                        gyro_path=SUNSIDED / "mpu6050_gyroscope.mat")
    assert len(sess.acc) == len(sess.gyro) == 10528
