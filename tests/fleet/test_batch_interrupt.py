"""Issue 27: Ctrl-C during ``imucal batch`` ends it with one line and exit 130, no traceback
(was: the LocalCluster's worker processes, which a terminal's Ctrl-C reaches too, died printing
theirs, and a cluster cut short while starting failed its exit-time close with another).

The batch runs as a child in a process group of its own, and the test sends SIGINT to the whole
group, as a terminal does: once the first worker process exists (it is then importing, the
moment that printed tracebacks), and once the first session is done (tasks running)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import imucal
from imucal.io.export import write_session_mat
from imucal.synth import make_session

pytestmark = pytest.mark.skipif(not hasattr(os, "killpg") or not Path("/proc").is_dir(),
                                reason="process groups and /proc (Linux)")
pytest.importorskip("distributed")

ROOT = Path(imucal.__file__).parents[1]


@pytest.fixture(scope="module")
def sessions(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("interrupt")
    for i in range(8):
        (root / f"u{i}").mkdir()
        sess, _ = make_session(poses=12, seed=40 + i)
        write_session_mat(root / f"u{i}" / "s.mat", sess)
    return root


def _start(sessions: Path, out: Path) -> subprocess.Popen:
    env = {k: v for k, v in os.environ.items() if k != "IMUCAL_DEBUG"}
    env["PYTHONPATH"] = str(ROOT)  # the imucal under test, in the workers too
    return subprocess.Popen(
        [sys.executable, "-c", "import sys; from imucal.cli.main import main; sys.exit(main())",
         "batch", str(sessions / "*" / "*.mat"), "--out-dir", str(out), "--workers", "1",
         "-v"], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        start_new_session=True)


def _a_worker_of(pid: int) -> bool:
    """A Dask worker process of ``pid`` exists (a spawned child other than multiprocessing's
    resource tracker)."""
    children = []
    for task in Path(f"/proc/{pid}/task").glob("*"):  # each thread's: Dask's start them
        try:
            children += (task / "children").read_text().split()
        except OSError:  # the thread ended meanwhile
            continue
    for child in children:
        try:
            cmd = Path(f"/proc/{child}/cmdline").read_bytes()
        except OSError:
            continue
        if b"spawn_main" in cmd and b"resource_tracker" not in cmd:
            return True
    return False


def _interrupt(proc: subprocess.Popen, sig: int = signal.SIGINT) -> tuple[int, str]:
    os.killpg(proc.pid, sig)  # the whole group, as Ctrl-C (or a closed terminal) does
    try:
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    return proc.returncode, err


def test_ctrl_c_while_the_workers_start(sessions, tmp_path):
    proc = _start(sessions, tmp_path / "out")
    end = time.monotonic() + 60
    while not _a_worker_of(proc.pid) and proc.poll() is None and time.monotonic() < end:
        time.sleep(0.01)
    assert proc.poll() is None, proc.communicate()
    rc, err = _interrupt(proc)
    assert "Traceback" not in err, err
    assert rc == 130 and err.endswith("imucal: interrupted\n"), (rc, err)
    assert err.count("\n") == 1, err


@pytest.mark.parametrize("sig", ["SIGINT", "SIGHUP"])  # SIGHUP killed the resource tracker
def test_ctrl_c_while_sessions_run(sessions, tmp_path, sig):
    proc = _start(sessions, tmp_path / "out")
    line = proc.stderr.readline()  # -v: a line after each session, the first once one is done
    assert line.startswith("done "), (line, proc.communicate())
    rc, err = _interrupt(proc, getattr(signal, sig))
    assert "Traceback" not in err, err
    assert rc == 130 and err.endswith("imucal: interrupted\n"), (rc, err)
    assert [ln for ln in err.splitlines() if not ln.startswith("done ")] == [
        "imucal: interrupted"], err
