"""A run either delivers every output or changes nothing (issue 11): fault injection.

Each case asserts the exit code, the one line on stderr (naming the file where there is one),
and that every file that was in the output directory before the run is byte-identical after
it, with nothing added (no temporary, no lock file).

Faults are real, not simulated inside imucal: a file-size limit (RLIMIT_FSIZE, so that every
writer, Rust ones included, gets EFBIG part-way through a file), a full tmpfs (ENOSPC; root
only), and signals sent by a test-only ``sitecustomize`` in the child: a Python audit hook that
fires at a chosen event (the session opened, calib.json's temporary complete, the recording's
layout module imported, the commit's first backup link). The product has no test hooks.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import resource
import shutil
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest

import imucal
from imucal.cli.main import main
from imucal.errors import ImucalError
from imucal.io.atomic import OWNER_SUFFIX, PREFIX, Transaction, owner_record
from imucal.io.export import write_session_mat
from imucal.synth import make_session

BIN = Path(sys.executable).parent
IMUCAL = shutil.which("imucal", path=str(BIN)) or str(BIN / "imucal")
ALL_OUTPUTS = ["--out", "calib.json", "--calibrated", "cal.csv", "--rrd", "run.rrd"]
# What the output directory holds before each run: other content than any run writes, and a
# previous run's gyroscope sidecar with the record that imucal wrote it (this session's gyroscope
# shares the accelerometer's clock).
OLD = {"calib.json": b'{"previous": "calib"}\n', "cal.csv": b"t,ax\n0,1\n",
       "cal.gyro.csv": b"t,gx\n0,0\n", "run.rrd": b"RRF2 old"}

HOOK = '''
import os, signal, sys, threading, time
spec = os.environ.get("IMUCAL_TEST_HOOK")
if spec:
    event, needle, count, action = spec.split("|")
    state = {"seen": 0, "busy": False}

    def fire():
        if action == "wait":  # hold the run here until the test says go
            open(os.environ["IMUCAL_TEST_READY"], "w").close()
            end = time.monotonic() + 60
            while not os.path.exists(os.environ["IMUCAL_TEST_GO"]) and time.monotonic() < end:
                time.sleep(0.02)
        elif "@" in action:  # a signal a little later, wherever the run then is
            name, delay = action.split("@")
            threading.Timer(float(delay), os.kill, (os.getpid(), getattr(signal, name))).start()
        else:
            os.kill(os.getpid(), getattr(signal, action))

    def hook(name, args):
        if state["busy"] or name != event or needle not in str(args):
            return
        state["seen"] += 1
        if state["seen"] == int(count):
            state["busy"] = True
            try:
                fire()
            finally:
                state["busy"] = False

    sys.addaudithook(hook)
'''


# --- helpers -----------------------------------------------------------------------------------


def snapshot(d: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(d.iterdir()) if p.is_file()}


def leftovers(d: Path) -> list[str]:
    """Temporaries and lock files (a record that imucal wrote a file stays with the file)."""
    return sorted(p.name for p in d.iterdir() if p.name.startswith(PREFIX)
                  and not p.name.endswith(OWNER_SUFFIX))


def fresh_dir(root: Path, name: str, files: dict[str, bytes] = OLD) -> Path:
    d = root / name
    d.mkdir()
    for n, b in files.items():
        (d / n).write_bytes(b)
        if n.endswith(".gyro.csv"):  # as a previous run leaves it (sha256sum's line)
            owner_record(d / n).write_text(f"{hashlib.sha256(b).hexdigest()}  {n}\n")
    return d


def one_line(stderr: str) -> str:
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    return lines[0]


def run_main(args: list[str], cwd: Path) -> tuple[int, str]:
    """``imucal ARGS`` in this process (a refusal needs no subprocess: fast)."""
    err = io.StringIO()
    old = os.getcwd()
    os.chdir(cwd)
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            rc = main([str(a) for a in args])
    finally:
        os.chdir(old)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)  # main() installs its own
    return rc, err.getvalue()


def _fsize(limit: int):
    return lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("session")
    sess, _ = make_session(poses=14, seed=5)
    write_session_mat(d / "s.mat", sess)
    return d / "s.mat"


@pytest.fixture(scope="module")
def hook_dir(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("hook")
    (d / "sitecustomize.py").write_text(HOOK)
    return d


def child_env(hook_dir: Path, hook: str | None = None, **extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("IMUCAL_DEBUG", "PYTHONPATH")}
    # the child runs the imucal under test (a worktree's, not the one the venv installed)
    env["PYTHONPATH"] = os.pathsep.join([str(hook_dir), str(Path(imucal.__file__).parents[1])])
    if hook:
        env["IMUCAL_TEST_HOOK"] = hook
    env.update(extra)
    return env


# --- every output requested, a fault at each point: all run at once ---------------------------

# name: (arguments after the session, hook, file-size limit as a function of the reference
# run's output sizes, expected exit code, what stderr's one line contains)
SCENARIOS = {
    "sigint while loading": ([], "open|s.mat|1|SIGINT", None, 130, "interrupted"),
    "sigint after calib.json's temporary": ([], "os.rename|" + PREFIX + "|1|SIGINT", None, 130,
                                            "interrupted"),
    "sigterm during the recording": ([], "import|viewer.blueprint|1|SIGTERM", None, 130,
                                     "interrupted"),
    # issue 27: SIGHUP (a terminal closed) is a polite kill like SIGTERM (was: the process died
    # on the spot, leaving calib.json's temporary and the lock files)
    "sighup after calib.json's temporary": ([], "os.rename|" + PREFIX + "|1|SIGHUP", None, 130,
                                            "interrupted"),
    "file too large: the table": ([], None, lambda s: 2 * s["calib.json"], 1,
                                  "cal.csv: could not be written: File too large"),
    "file too large: the recording": ([], None, lambda s: (s["cal.csv"] + s["run.rrd"]) // 2,
                                      1, "run.rrd: could not be written: File too large"),
    "non-ascii output": (["--out", "é.json"], None, None, 0, ""),
}


@pytest.fixture(scope="module")
def runs(tmp_path_factory, session, hook_dir) -> dict[str, tuple]:
    root = tmp_path_factory.mktemp("runs")
    ref = fresh_dir(root, "reference", {})
    args = [IMUCAL, "calibrate", str(session), *ALL_OUTPUTS]
    proc = subprocess.run(args, cwd=ref, capture_output=True, text=True, timeout=120,
                          env=child_env(hook_dir))
    assert proc.returncode == 0, proc.stderr
    sizes = {p.name: p.stat().st_size for p in ref.iterdir()}
    # the limits above fall between two outputs' sizes
    assert 2 * sizes["calib.json"] < sizes["cal.csv"] < 0.8 * sizes["run.rrd"], sizes
    assert leftovers(ref) == []
    procs = {}
    for name, (more, hook, limit, _, _) in SCENARIOS.items():
        d = fresh_dir(root, name.replace(" ", "_").replace("'", "").replace(":", ""))
        env = child_env(hook_dir, hook, PYTHONIOENCODING="ascii")
        cmd = [IMUCAL, "calibrate", str(session), *ALL_OUTPUTS, *more]
        procs[name] = (d, snapshot(d), subprocess.Popen(
            cmd, cwd=d, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            preexec_fn=None if limit is None else _fsize(limit(sizes))))
    done = {}
    for name, (d, before, p) in procs.items():
        out, err = p.communicate(timeout=180)
        done[name] = (d, before, p.returncode, out, err)
    done["reference"] = (ref, {}, 0, proc.stdout, proc.stderr)
    return done


@pytest.mark.parametrize("name", [n for n in SCENARIOS if SCENARIOS[n][3] != 0])
def test_a_failed_or_interrupted_run_changes_nothing(runs, name):
    d, before, rc, out, err = runs[name]
    _, _, _, expected_rc, needle = SCENARIOS[name]
    assert rc == expected_rc, (rc, err)
    assert needle in one_line(err)
    assert snapshot(d) == before  # byte-identical, nothing added
    assert leftovers(d) == []
    assert "Traceback" not in err


def test_a_completed_run_delivers_every_output_and_removes_a_stale_sidecar(runs):
    d, before, rc, out, err = runs["non-ascii output"]
    assert rc == 0 and err == "", err
    ref = runs["reference"][0]
    after = snapshot(d)
    # calib.json is byte-identical between runs of one session (test_robustness): the very
    # file a clean run makes; the summary names a non-ASCII file with an escape.
    assert after["é.json"] == (ref / "calib.json").read_bytes()
    assert after["cal.csv"] == (ref / "cal.csv").read_bytes()
    assert after["run.rrd"][:3] == b"RRF" and after["run.rrd"] != before["run.rrd"]
    assert "cal.gyro.csv" not in after  # the previous run's sidecar: stale, removed
    assert "wrote \\xe9.json" in out and "removed cal.gyro.csv" in out
    assert after["calib.json"] == before["calib.json"]  # not an output of this run
    assert leftovers(d) == []


def test_an_interrupt_during_the_commit_waits_for_it(tmp_path, session, hook_dir):
    """SIGINT at the commit's first step is held back until every output is in place: exit
    130, and all outputs new (none old, none half)."""
    d = fresh_dir(tmp_path, "commit")
    env = child_env(hook_dir, "os.link|" + PREFIX + "|1|SIGINT")
    proc = subprocess.run([IMUCAL, "calibrate", str(session), *ALL_OUTPUTS], cwd=d, env=env,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 130 and "interrupted" in one_line(proc.stderr)
    after = snapshot(d)
    assert all(after[n] != OLD[n] for n in ("calib.json", "cal.csv", "run.rrd"))
    assert json.loads(after["calib.json"])["format"] == "imucal-calibration"
    assert "cal.gyro.csv" not in after and leftovers(d) == []


def test_a_second_run_on_the_same_outputs_is_refused(tmp_path, session, hook_dir):
    d = fresh_dir(tmp_path, "busy")
    ready, go = tmp_path / "ready", tmp_path / "go"
    env = child_env(hook_dir, "open|s.mat|1|wait", IMUCAL_TEST_READY=str(ready),
                    IMUCAL_TEST_GO=str(go))
    first = subprocess.Popen([IMUCAL, "calibrate", str(session), "--out", "calib.json",
                              "--calibrated", "cal.csv"], cwd=d, env=env,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        end = time.monotonic() + 60
        while not ready.exists() and first.poll() is None and time.monotonic() < end:
            time.sleep(0.02)
        assert ready.exists(), first.communicate()
        before = snapshot(d)
        # the same table under another calibration file: the table is in use
        rc, err = run_main(["calibrate", session, "--out", "other.json", "--calibrated",
                            "cal.csv"], d)
        assert rc == 1 and one_line(err) == "imucal: error: cal.csv: in use by another imucal run"
        assert snapshot(d) == before
    finally:
        go.touch()
        out, err = first.communicate(timeout=120)
    assert first.returncode == 0, err
    assert (d / "calib.json").read_bytes() != OLD["calib.json"] and leftovers(d) == []


def test_a_full_disk_is_one_line_and_no_hang(tmp_path, session):
    """A real ENOSPC (a 256 kB tmpfs): the recording's writer used to wait forever on it."""
    d = tmp_path / "full"
    d.mkdir()
    if os.geteuid() != 0 or subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs",
                                            str(d)], capture_output=True).returncode != 0:
        pytest.skip("mounting a small tmpfs needs root (and a container that allows it)")
    try:
        for n in ("calib.json", "run.rrd"):
            (d / n).write_bytes(OLD[n])
        before = snapshot(d)
        proc = subprocess.run([IMUCAL, "calibrate", str(session), "--out", "calib.json",
                               "--rrd", "run.rrd"], cwd=d, capture_output=True, text=True,
                              timeout=120)
        assert proc.returncode == 1
        assert "run.rrd: could not be written: No space left on device" in one_line(proc.stderr)
        assert snapshot(d) == before and leftovers(d) == []
    finally:
        subprocess.run(["umount", str(d)], check=False)


# --- targets refused before any work ------------------------------------------------------------


def _special_targets(d: Path, ext: str) -> dict[str, str]:
    """Targets imucal must refuse, named ``*ext``, with what the error says about each."""
    os.mkfifo(d / f"fifo{ext}")
    (d / f"dir{ext}").mkdir()
    (d / f"readonly{ext}").write_bytes(b"keep")
    os.chmod(d / f"readonly{ext}", 0o444)
    os.symlink("/proc/self/fd/1", d / f"stdout{ext}")
    os.symlink(f"loop-b{ext}", d / f"loop-a{ext}")
    os.symlink(f"loop-a{ext}", d / f"loop-b{ext}")
    long = "x" * 300 + ext
    return {f"fifo{ext}": "is a FIFO (named pipe), not a regular file",
            f"dir{ext}": "is a directory", f"newname{ext}/": "names a directory",
            f"readonly{ext}": "is read-only", f"stdout{ext}": "is a process's open file",
            f"loop-a{ext}": "is a loop of symbolic links",
            "-": "unknown output format" if ext == ".csv" else "standard output",
            long: f"the file name is {len(long)} bytes long"}


@pytest.mark.parametrize("option", ["--out", "--rrd", "--calibrated", "apply"])
def test_targets_that_are_not_plain_writable_files_are_refused(tmp_path, session, option):
    d = tmp_path / "targets"
    d.mkdir()
    ext = {"--out": ".json", "--rrd": ".rrd"}.get(option, ".csv")
    cases = _special_targets(d, ext)
    (d / "calib.json").write_bytes(OLD["calib.json"])
    before = snapshot(d)
    for target, needle in cases.items():
        if option == "apply":
            args = ["apply", "calib.json", session, "--out", target]
        elif option == "--out":
            args = ["calibrate", session, "--out", target]
        else:
            args = ["calibrate", session, "--out", "new.json", option, target]
        rc, err = run_main(args, d)
        line = one_line(err)
        assert rc == 1 and line.startswith(f"imucal: error: {target}: output path: "), line
        assert needle in line, (needle, line)
        assert snapshot(d) == before and leftovers(d) == []
        assert not (d / "new.json").exists() and not (d / f"newname{ext}").exists()


def test_a_device_node_is_refused(tmp_path, session):
    dev = tmp_path / "null.json"
    try:
        os.mknod(dev, stat.S_IFCHR | 0o666, os.makedev(1, 3))
    except (PermissionError, OSError) as e:
        pytest.skip(f"cannot make a device node here ({e.strerror})")
    rc, err = run_main(["calibrate", session, "--out", "null.json"], tmp_path)
    assert rc == 1 and "null.json: output path: is a character device" in one_line(err)
    assert stat.S_ISCHR(os.stat(dev).st_mode)


# --- user input that used to be an internal error (exit 3) ---------------------------------------


@pytest.mark.parametrize("args, rc, needle", [
    (["--g", "1e-300"], 2, "'--g'"),
    (["--lambda", "1e308"], 2, "'--lambda'"),
    (["--gyro-lambda", "1e308"], 2, "'--gyro-lambda'"),
])
def test_extreme_scales_are_usage_errors(tmp_path, session, args, rc, needle):
    code, err = run_main(["calibrate", session, "--out", "c.json", *args], tmp_path)
    assert code == rc and needle in err and "Traceback" not in err
    assert not (tmp_path / "c.json").exists()


def test_a_symlink_loop_as_input_is_one_line(tmp_path):
    os.symlink("b.mat", tmp_path / "a.mat")
    os.symlink("a.mat", tmp_path / "b.mat")
    rc, err = run_main(["calibrate", "a.mat", "--out", "c.json"], tmp_path)
    assert rc == 1 and one_line(err) == "imucal: error: a.mat: is a loop of symbolic links"


@pytest.fixture(scope="module")
def good_calibration(tmp_path_factory, session) -> dict:
    d = tmp_path_factory.mktemp("calfile")
    result = imucal.calibrate(imucal.load_session(session))
    imucal.save_calibration(result, d / "c.json")
    return json.loads((d / "c.json").read_text())


def _edit(data: dict, path: list, value) -> dict:
    data = json.loads(json.dumps(data))
    node = data
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    return data


ACC = ["segments", 0, "accelerometer"]
BAD_CALIBRATIONS = {
    "T = 0": (ACC + ["T"], [[0, 0, 0]] * 3, "segments[0].accelerometer: malformed calibration: "
              "T is singular"),
    "K = 0": (ACC + ["K"], [1, 0, 1], "a scale factor in K is zero"),
    "K null": (ACC + ["K"], [1, None, 1], "K must be finite numbers"),
    "b true": (ACC + ["b"], [True, 0, 0], "b must hold numbers"),
    "g NaN": (["units", "g"], float("nan"), "units.g: malformed calibration: g must be finite"),
    "g 0": (["units", "g"], 0, "g must be > 0"),
    "format_version true": (["format_version"], True, "format_version: format_version True"),
    "format_version 1.0": (["format_version"], 1.0, "format_version 1.0 is not supported"),
    "unit": (["units", "accelerometer"], "furlongs", "accelerometer 'furlongs' is not one of"),
    "time order": (["segments", 0, "t_end"], -1e9, "not in time order"),
}


@pytest.mark.parametrize("case", list(BAD_CALIBRATIONS))
def test_every_parameter_of_a_calibration_file_is_checked_on_load(tmp_path, session,
                                                                  good_calibration, case):
    path, value, needle = BAD_CALIBRATIONS[case]
    (tmp_path / "bad.json").write_text(json.dumps(_edit(good_calibration, path, value)))
    with pytest.raises(ImucalError) as e:
        imucal.load_calibration(tmp_path / "bad.json")
    assert needle in str(e.value) and str(e.value).startswith(str(tmp_path / "bad.json"))
    rc, err = run_main(["apply", "bad.json", session, "--out", "o.csv"], tmp_path)
    assert rc == 1 and needle in one_line(err) and not (tmp_path / "o.csv").exists()


def test_a_good_calibration_file_still_loads(tmp_path, good_calibration):
    (tmp_path / "c.json").write_text(json.dumps(good_calibration))
    cal = imucal.load_calibration(tmp_path / "c.json")
    assert cal.g == good_calibration["units"]["g"] and len(cal.segments) >= 1


def test_deeply_nested_json_is_one_line(tmp_path, session):
    (tmp_path / "deep.json").write_text("[" * 100_000 + "]" * 100_000)
    rc, err = run_main(["apply", "deep.json", session, "--out", "o.csv"], tmp_path)
    assert rc == 1 and one_line(err) == ("imucal: error: deep.json: not a calibration file: "
                                         "JSON nested too deeply")


# --- the transaction itself ----------------------------------------------------------------------


def test_a_failed_rename_in_the_commit_puts_the_first_back(tmp_path, monkeypatch):
    for n in ("a.txt", "b.txt"):
        (tmp_path / n).write_text(f"old {n}")
    real = os.replace
    calls = []

    def flaky(src, dst, *a, **k):
        calls.append(dst)
        if Path(dst).name == "b.txt":
            raise OSError(5, "Input/output error")
        return real(src, dst, *a, **k)

    with pytest.raises(ImucalError, match="b.txt: could not be put in place: Input/output"), \
            Transaction([tmp_path / "a.txt", tmp_path / "b.txt", tmp_path / "c.txt"]) as tx:
        for n in ("a.txt", "b.txt", "c.txt"):
            tx.temp(tmp_path / n).write_text(f"new {n}")
        monkeypatch.setattr(os, "replace", flaky)
        tx.commit()
    assert [p.name for p in sorted(tmp_path.iterdir())] == ["a.txt", "b.txt"]
    assert (tmp_path / "a.txt").read_text() == "old a.txt"  # renamed, then put back
    assert (tmp_path / "b.txt").read_text() == "old b.txt"


def test_a_killed_runs_leftovers_go_with_the_next_run(tmp_path):
    target = tmp_path / "calib.json"
    with Transaction([target]) as tx:
        tmp = tx.temp(target)
        tmp.write_text("half")
        os.link(tmp, tmp_path / "kept")  # what a SIGKILL would leave: the temporary
        tx.commit()
    os.rename(tmp_path / "kept", tmp)
    assert leftovers(tmp_path) == [tmp.name]
    with Transaction([target]):
        pass
    assert leftovers(tmp_path) == []


def test_the_recording_encoder_is_bounded():
    from viewer.rrd_file import flush

    class Stuck:  # Rerun's flush on a sink that never drains: waits, then "timed out"
        waits: list[float] = []

        def flush(self, timeout_sec):
            self.waits.append(timeout_sec)
            time.sleep(timeout_sec)
            raise RuntimeError("Flush timed out - not all log messages were sent")

    with pytest.raises(ImucalError, match="not encoded within 0.5 s"):
        flush(Stuck(), timeout=0.5)
    # Rerun's wait does not return to Python on a signal: each wait is short, so a Ctrl-C is
    # acted on within one of them.
    assert len(Stuck.waits) >= 2 and max(Stuck.waits) <= 0.25


# --- imucal view: never replaces a file the user did not name ------------------------------------


def test_view_without_display_picks_a_free_name(tmp_path, session, monkeypatch, capsys):
    from viewer.app import show

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    (tmp_path / "s.rrd").write_bytes(b"someone's file")
    (tmp_path / "s-1.rrd").write_bytes(b"another")
    monkeypatch.chdir(tmp_path)
    assert show(str(session)) == 0
    assert "wrote " + str(tmp_path / "s-2.rrd") in capsys.readouterr().out
    assert (tmp_path / "s.rrd").read_bytes() == b"someone's file"
    assert (tmp_path / "s-1.rrd").read_bytes() == b"another"
    assert (tmp_path / "s-2.rrd").read_bytes()[:3] == b"RRF"
    (tmp_path / "garbage.rrd").write_bytes(b"not a recording")
    rc, err = run_main(["view", "garbage.rrd", "--save", "copy.rrd"], tmp_path)
    assert rc == 1 and "garbage.rrd: not a Rerun recording" in one_line(err)
    assert not (tmp_path / "copy.rrd").exists() and leftovers(tmp_path) == []


def test_the_longest_name_the_file_system_allows_is_written(tmp_path):
    """Temporaries, backups and lock files have short names of their own: a 255-byte target
    name (the usual NAME_MAX) is written, replaced, and nothing else is left."""
    target = tmp_path / ("x" * 250 + ".json")
    for content in ("first", "second"):
        with Transaction([target]) as tx:
            tx.temp(target).write_text(content)
            tx.commit()
        assert target.read_text() == content
    assert [p.name for p in tmp_path.iterdir()] == [target.name]
