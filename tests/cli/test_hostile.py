"""Issue 27's hostile cases: a file the user did not name is never touched, contradictory
inputs are refused before any work, and bad inputs get the README's exit codes and one line."""

from __future__ import annotations

import contextlib
import io
import os
import signal
from pathlib import Path

import pytest

from imucal.cli.main import main
from imucal.io.export import write_session_mat
from imucal.synth import make_session


def run(args: list, cwd: Path | None = None) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    old = os.getcwd()
    if cwd is not None:
        os.chdir(cwd)
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
            rc = main([str(a) for a in args])
    finally:
        os.chdir(old)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)  # main() installs its own
    return rc, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def own_clock(tmp_path_factory) -> Path:
    """A session whose gyroscope has timestamps of its own: calibrated tables get a sidecar."""
    d = tmp_path_factory.mktemp("own_clock")
    sess, _ = make_session(poses=12, seed=3, gyro_rate=125.0)
    write_session_mat(d / "s.mat", sess)
    return d / "s.mat"


@pytest.fixture(scope="module")
def calib(tmp_path_factory, own_clock) -> Path:
    d = tmp_path_factory.mktemp("calib")
    rc, _, err = run(["calibrate", own_clock, "--out", d / "c.json"])
    assert rc == 0, err
    return d / "c.json"


# --- item 1: a file the user never named ------------------------------------------------------


@pytest.mark.parametrize("ext", ["csv", "parquet"])
def test_apply_never_replaces_a_sidecar_name_it_did_not_write(tmp_path, own_clock, calib, ext):
    mine = tmp_path / f"out.gyro.{ext}"
    mine.write_bytes(b"the user's own file\n")
    rc, out, err = run(["apply", calib, own_clock, "--out", tmp_path / f"out.{ext}"])
    assert rc == 1
    assert err.count("\n") == 1 and f"out.gyro.{ext}" in err and "did not write it" in err
    assert mine.read_bytes() == b"the user's own file\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == [mine.name]  # nothing else written


def test_a_sidecar_imucal_wrote_is_replaced_and_one_edited_since_is_not(tmp_path, own_clock,
                                                                          calib):
    table, side = tmp_path / "out.csv", tmp_path / "out.gyro.csv"
    for _ in range(2):  # the second run replaces the first run's sidecar: its own
        rc, out, err = run(["apply", calib, own_clock, "--out", table])
        assert rc == 0, err
        assert f"wrote {side}" in out
    first = side.read_bytes()
    assert first.startswith(b"t,gx,gy,gz\n")
    side.write_bytes(first + b"1e9,0,0,0\n")  # the user's edit: no longer what imucal wrote
    rc, _, err = run(["apply", calib, own_clock, "--out", table])
    assert rc == 1 and "out.gyro.csv" in err and "did not write it" in err
    assert side.read_bytes() == first + b"1e9,0,0,0\n"


def test_calibrate_never_removes_a_sidecar_name_it_did_not_write(tmp_path, sample_session_path):
    """The sample's gyroscope shares the accelerometer's clock: no sidecar to write, and an
    unrelated cal.gyro.csv was removed as "a previous run's" before issue 27."""
    mine = tmp_path / "cal.gyro.csv"
    mine.write_text("t,gx\n0,0\n")
    rc, _, err = run(["calibrate", sample_session_path, "--out", tmp_path / "c.json",
                      "--calibrated", tmp_path / "cal.csv"])
    assert rc == 1 and "cal.gyro.csv" in err and "did not write it" in err
    assert mine.read_text() == "t,gx\n0,0\n"
    assert not (tmp_path / "c.json").exists()


# --- contradictory inputs: refused before any work ---------------------------------------------


@pytest.fixture(scope="module")
def two_files(tmp_path_factory) -> dict[str, Path]:
    """A session as one table with both sensors, and as an accelerometer and a gyroscope file."""
    import numpy as np

    from imucal.io.export import write_session_csv

    d = tmp_path_factory.mktemp("two_files")
    sess, _ = make_session(poses=6, seed=1)
    write_session_csv(d / "both.csv", sess)
    np.savetxt(d / "acc.csv", np.column_stack([sess.t_acc, sess.acc]), delimiter=",",
               header="t,ax,ay,az", comments="")
    np.savetxt(d / "gyr.csv", np.column_stack([sess.t_gyro, sess.gyro]), delimiter=",",
               header="t,gx,gy,gz", comments="")
    return {p.name: p for p in d.iterdir()}


@pytest.mark.parametrize(("session", "gyro", "more", "needle"), [
    ("acc.csv", "gyr.csv", ["--acc-only"], "acc.csv: --gyro: --acc-only calibrates the "
     "accelerometer alone, but --gyro gyr.csv names a gyroscope"),
    ("acc.csv", "acc.csv", [], "acc.csv: --gyro: is the session file itself"),
    ("both.csv", "gyr.csv", [], "both.csv: --gyro: has a gyroscope of its own, and --gyro "
     "gyr.csv names another"),
])
def test_contradictory_inputs_are_refused(tmp_path, two_files, session, gyro, more, needle):
    for command in (["calibrate", two_files[session], "--out", tmp_path / "c.json"],
                    ["noise", two_files[session], "--gyro-unit", "rad/s"]):
        rc, out, err = run([*command, "--gyro", two_files[gyro], *more])
        assert rc == 1 and err.count("\n") == 1 and needle in err, err
        assert "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def test_a_two_file_session_still_loads(two_files):
    from imucal.io.load import load_session

    sess = load_session(two_files["acc.csv"], gyro_path=two_files["gyr.csv"])
    assert sess.has_gyro and len(sess.gyro) == len(sess.acc)


def test_acc_only_with_a_gyroscope_stream_is_refused(two_files):
    from imucal.errors import ImucalError
    from imucal.io.load import load_session

    with pytest.raises(ImucalError, match="--acc-only calibrates the accelerometer alone, but "
                                          "--gyro /imu/gyro names a gyroscope"):
        load_session(two_files["both.csv"], acc_only=True, select={"gyro": "/imu/gyro"})


# --- messages and exit codes (the README's contract) -------------------------------------------


def test_a_rate_no_imu_records_is_a_usage_error(tmp_path, two_files):
    rc, _, err = run(["calibrate", two_files["acc.csv"], "--acc-only", "--rate", "1e-300",
                      "--out", tmp_path / "c.json"])
    assert rc == 2 and "--rate" in err and "one sample a minute" in err  # was exit 3


def test_turns_too_fast_for_the_sample_period_are_one_line(tmp_path):
    """Timestamps ten times too coarse for the turns: RK4 overflows; said as the data's, exit 1
    (was an internal error, exit 3)."""
    import numpy as np

    sess, _ = make_session(poses=6, seed=1)
    path = tmp_path / "slow.txt"
    np.savetxt(path, np.column_stack([sess.acc, sess.gyro])[:3000])
    rc, _, err = run(["calibrate", path, "--rate", "0.1", "--acc-unit", "g", "--gyro-unit",
                      "rad/s", "--out", tmp_path / "c.json"])
    assert rc == 1 and err.count("\n") == 1
    assert "the turns cannot be integrated" in err and "check --rate" in err


@pytest.mark.parametrize(("path", "what"), [("/dev/zero", "character device"),
                                            ("/dev/urandom", "character device"),
                                            ("FIFO", "FIFO (named pipe)")])
def test_devices_and_fifos_are_said_as_such(tmp_path, path, what):
    if path == "FIFO":
        path = tmp_path / "f.csv"
        os.mkfifo(path)  # no writer: a reader that opened it would wait forever

    def stuck(signum, frame):
        raise TimeoutError("blocked reading the FIFO (it was opened)")

    previous = signal.signal(signal.SIGALRM, stuck)
    signal.alarm(30)
    try:
        for command in (["calibrate", path, "--out", tmp_path / "c.json"], ["noise", path]):
            rc, _, err = run(command)
            assert rc == 1 and f"is a {what}" in err and "empty" not in err, err
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def _read(path: Path):
    from imucal.io.load import load_session

    return load_session(path, gyro_unit="rad/s")


def test_cr_line_endings_and_comment_lines_are_read(tmp_path, two_files):
    import numpy as np

    from imucal.errors import ImucalError

    text = two_files["both.csv"].read_bytes()
    ref = _read(two_files["both.csv"])
    (tmp_path / "cr.csv").write_bytes(text.replace(b"\n", b"\r"))  # classic Mac OS
    lines = text.split(b"\n")
    commented = [b"# logger v2", lines[0], b"# pose 1", *lines[1:500], b"  # pose 2",
                 *lines[500:]]
    (tmp_path / "comments.csv").write_bytes(b"\n".join(commented))
    for name in ("cr.csv", "comments.csv"):
        sess = _read(tmp_path / name)
        assert np.array_equal(sess.acc, ref.acc) and np.array_equal(sess.gyro, ref.gyro)
        assert np.array_equal(sess.t_acc, ref.t_acc)
    assert any("2 comment lines (#) among the rows skipped" in n for n in
               _read(tmp_path / "comments.csv").notes)
    # A ragged row after the comments is still named by its own line number.
    commented[700] = b"1,2,3"
    (tmp_path / "ragged.csv").write_bytes(b"\n".join(commented))
    with pytest.raises(ImucalError, match="line 701 has 3 fields, expected 7"):
        _read(tmp_path / "ragged.csv")


def _unprivileged() -> list[str] | None:
    """A command prefix that runs without the power to read any file, or None."""
    import shutil

    if os.geteuid() != 0:
        return []
    setpriv = shutil.which("setpriv")
    return None if setpriv is None else [setpriv, "--bounding-set",
                                         "-dac_override,-dac_read_search"]


def _imucal() -> str:
    import shutil
    import sys

    return shutil.which("imucal", path=str(Path(sys.executable).parent)) or "imucal"


def test_an_unreadable_file_is_exit_1_naming_it(tmp_path, two_files):
    import subprocess

    prefix = _unprivileged()
    if prefix is None:
        pytest.skip("root without setpriv: every file is readable")
    path = tmp_path / "locked.csv"
    path.write_bytes(two_files["both.csv"].read_bytes())
    path.chmod(0)
    env = {k: v for k, v in os.environ.items() if k != "IMUCAL_DEBUG"}
    for command in (["calibrate", path, "--out", tmp_path / "c.json"], ["noise", path],
                    ["export", path, "--to", "px4"]):
        proc = subprocess.run([*prefix, _imucal(), *map(str, command)], capture_output=True,
                              text=True, env=env, timeout=120)
        assert proc.returncode == 1, proc.stderr  # was 2, a usage error
        line, = proc.stderr.strip().splitlines()
        assert line.startswith("imucal: error: ") and line.endswith(
            "locked.csv: cannot be read (Permission denied)"), line


def test_a_full_disk_names_the_file(tmp_path):
    """imucal synth through write_atomic: the limit on a file's size stops the write (EFBIG,
    as a full disk's ENOSPC would); the line names the file (it did not)."""
    import resource
    import subprocess

    proc = subprocess.run([_imucal(), "synth", "s.mat", "--poses", "12"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=120,
                          preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_FSIZE,
                                                                (20_000, 20_000)))
    assert proc.returncode == 1
    assert proc.stderr.strip().splitlines() == [
        "imucal: error: s.mat: could not be written: File too large; the previous file, if "
        "any, is unchanged"], proc.stderr
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("compress", [False, True])
@pytest.mark.parametrize(("var", "make", "what"), [
    ("acc", lambda a: a.astype(complex), "complex numbers"),
    ("acc", lambda a: __import__("scipy.sparse").sparse.csc_matrix(a), "a sparse matrix"),
    ("gyro", lambda a: __import__("scipy.sparse").sparse.csc_matrix(a), "a sparse matrix"),
    ("acc", lambda a: "text", "text (char)"),
])
def test_a_mat_variable_that_is_not_real_numbers_is_said(tmp_path, var, make, what, compress):
    from scipy.io import savemat

    from imucal.errors import ImucalError
    from imucal.io.load import load_session

    sess, _ = make_session(poses=4, seed=1)
    data = {"acc": sess.acc, "gyro": sess.gyro, "t": sess.t_acc}
    data[var] = make(data[var])
    savemat(tmp_path / "s.mat", data, do_compression=compress)
    with pytest.raises(ImucalError) as e:
        load_session(tmp_path / "s.mat")
    assert str(e.value).startswith(f"s.mat: {var}: the variable {var!r} holds {what}, not real "
                                   "numbers")


@pytest.mark.parametrize(("var", "what"), [("acc", "complex numbers"), ("gyro", "a sparse matrix")])
def test_a_v73_variable_that_is_not_real_numbers_is_said(tmp_path, var, what):
    """MATLAB v7.3 (HDF5): complex numbers as a compound of real and imag, a sparse matrix as a
    group, as MATLAB writes them."""
    import h5py
    import numpy as np

    from imucal.errors import ImucalError
    from imucal.io.load import load_session

    sess, _ = make_session(poses=4, seed=1)
    with h5py.File(tmp_path / "s.mat", "w", userblock_size=512) as f:
        for name, values in (("acc", sess.acc), ("gyro", sess.gyro), ("t", sess.t_acc)):
            if name == var == "acc":
                cplx = np.zeros((3, len(values)), dtype=[("real", "<f8"), ("imag", "<f8")])
                cplx["real"] = values.T
                f.create_dataset(name, data=cplx).attrs["MATLAB_class"] = np.bytes_("double")
            elif name == var:
                g = f.create_group(name)
                g.attrs["MATLAB_class"] = np.bytes_("double")
                g.attrs["MATLAB_sparse"] = 3
                g.create_dataset("data", data=values.ravel())
            else:
                f.create_dataset(name, data=np.atleast_2d(values.T)).attrs["MATLAB_class"] = (
                    np.bytes_("double"))
    with pytest.raises(ImucalError) as e:
        load_session(tmp_path / "s.mat")
    assert str(e.value).startswith(f"s.mat: {var}: the variable {var!r} holds {what}, not real")
