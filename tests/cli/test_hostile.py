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
