"""How ``imucal-view`` starts a viewer: its servers on 127.0.0.1 and on ports that are checked
first, a quiet terminal (the viewer's log only with -v, a failure as one line), --version and
shell completion.

The web-viewer tests run the real ``imucal-view`` and ``rerun``; the native one needs a display
(``xvfb-run``, Debian package ``xvfb``) and a Vulkan renderer (``mesa-vulkan-drivers``), and is
skipped naming the package where one is absent (in CI, where .ci/run installs the renderer, a
missing renderer fails instead). Every process started here gets its own process group and is
ended by its group id.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import select
import shutil
import socket
import stat
import subprocess
import sys
import time
import urllib.request
from importlib.metadata import version
from pathlib import Path

import pytest
from viewer_env import need, stop_group, vulkan_missing

import imucal
from viewer.app import DEFAULT_WEB_PORT, free_port, native_command, port_taken, show

ROOT = Path(__file__).resolve().parents[2]
RERUN = Path(sys.executable).parent / "rerun"
VIEW = [sys.executable, "-c", "from imucal.cli import view_main; view_main()"]
IMUCAL = [sys.executable, "-c", "import sys; from imucal.cli import main; sys.exit(main())"]
needs_rerun = pytest.mark.skipif(not RERUN.exists(), reason="the rerun executable is not in "
                                 "the venv (pip install -e .)")


@pytest.fixture(scope="module")
def rrd(tmp_path_factory, sample_session_path) -> Path:
    from viewer.recording import save_recording

    path = tmp_path_factory.mktemp("launch") / "session.rrd"
    save_recording(imucal.calibrate(imucal.load_session(sample_session_path)), path)
    return path


def _env(tmp_path: Path, **extra: str) -> dict[str, str]:
    """A private HOME and XDG directories: rerun's first run (its analytics notice, its
    config) happens here, whatever the machine's own state."""
    home = tmp_path / "home"
    home.mkdir(exist_ok=True)
    env = dict(os.environ, HOME=str(home), XDG_CONFIG_HOME=str(home / ".config"),
               XDG_DATA_HOME=str(home / ".local" / "share"), **extra)
    env.pop("RUST_LOG", None)
    return env


@contextlib.contextmanager
def _held(port: int):
    """A server of someone else's listening on 127.0.0.1:``port`` (if the port is already
    held by another program, it is held all the same)."""
    s = socket.socket()
    try:
        try:
            s.bind(("127.0.0.1", port))
            s.listen()
        except OSError as e:
            if e.errno != errno.EADDRINUSE:
                raise
        assert port_taken(port)
        yield
    finally:
        s.close()


def _start(cmd: list[str], env: dict, **kw) -> subprocess.Popen:
    return subprocess.Popen(cmd, env=env, start_new_session=True, text=True, **kw)


def _stop(proc: subprocess.Popen) -> None:
    stop_group(proc, timeout=20)


def _readline(proc: subprocess.Popen, timeout: float) -> str:
    ready, _, _ = select.select([proc.stdout], [], [], timeout)
    return proc.stdout.readline() if ready else ""


def _listening(port: int) -> list[str]:
    """The local addresses (IPv4, from /proc/net/tcp*) a socket listens on ``port`` at."""
    found = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        with contextlib.suppress(OSError), open(table) as f:
            for row in f.read().splitlines()[1:]:
                local, state = row.split()[1], row.split()[3]
                host, hexport = local.split(":")
                if state == "0A" and int(hexport, 16) == port:  # 0A: LISTEN
                    if len(host) == 8:
                        found.append(socket.inet_ntoa(bytes.fromhex(host)[::-1]))
                    else:
                        found.append("::" if int(host, 16) == 0 else host)
    return found


# --- the command line built, with a stand-in viewer --------------------------------------------


def _fake_rerun(tmp_path: Path, body: str) -> Path:
    """A ``rerun`` that records its arguments and environment, then runs ``body`` (sh)."""
    script = tmp_path / "rerun"
    script.write_text(f'#!/bin/sh\necho "$@" > "{tmp_path}/argv"\n'
                      f'echo "RUST_LOG=$RUST_LOG" > "{tmp_path}/env"\n{body}\n')
    script.chmod(script.stat().st_mode | stat.S_IXUSR)
    return script


def test_native_viewer_binds_loopback_on_a_free_grpc_port(rrd, tmp_path, monkeypatch, capsys):
    cmd = native_command("rerun", "x.rrd", 45678)
    assert cmd[cmd.index("--bind") + 1] == "127.0.0.1" and cmd[cmd.index("--port") + 1] == "45678"
    fake = _fake_rerun(tmp_path, "echo INFO Listening on 127.0.0.1; echo WARN docker >&2")
    monkeypatch.setattr("viewer.app.rerun_executable", lambda: str(fake))
    monkeypatch.setenv("DISPLAY", ":99")
    monkeypatch.delenv("RUST_LOG", raising=False)
    with _held(9876):  # rerun's default port: a viewer already there must not get the file
        assert show(str(rrd)) == 0
    argv = (tmp_path / "argv").read_text().split()
    assert argv[argv.index("--bind") + 1] == "127.0.0.1"
    grpc = int(argv[argv.index("--port") + 1])
    assert grpc != 9876 and not port_taken(grpc)
    assert argv[-1] == str(rrd)
    assert (tmp_path / "env").read_text().strip() == "RUST_LOG=warn"
    out = capsys.readouterr()
    assert out.out == out.err == ""  # the viewer's own lines stay in its log

    assert show(str(rrd), bind="0.0.0.0", grpc_port=grpc) == 0  # asked for: as asked
    argv = (tmp_path / "argv").read_text().split()
    assert argv[argv.index("--bind") + 1] == "0.0.0.0"
    assert argv[argv.index("--port") + 1] == str(grpc)


def test_a_failing_viewer_is_one_line_and_its_log_only_with_verbose(rrd, tmp_path, monkeypatch,
                                                                     capfd):
    log = tmp_path / "rerun.log"
    log.write_text("\n".join(["INFO Telemetry initialized"] * 12 + [
        "\033[31mERROR\033[0m eframe::native::run: Exiting because of error: no adapter",
        "Error: app creation error: Failed to get render context"]) + "\n")
    fake = _fake_rerun(tmp_path, f'cat "{log}" >&2; exit 3')
    monkeypatch.setattr("viewer.app.rerun_executable", lambda: str(fake))
    monkeypatch.setenv("DISPLAY", ":99")
    from viewer.app import view

    assert view(str(rrd)) == 1
    out, err = capfd.readouterr()
    assert out == ""
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("imucal-view: the viewer stopped (exit code 3): app creation "
                               "error: Failed to get render context")
    assert "mesa-vulkan-drivers" in lines[0] and "\033" not in lines[0]

    assert view(str(rrd), verbose=True) == 1
    out, err = capfd.readouterr()
    assert err.count("Telemetry initialized") == 12 and err.splitlines()[-1].startswith(
        "imucal-view: the viewer stopped (exit code 3)")


def test_bind_must_be_an_address(rrd, tmp_path):
    out = subprocess.run([*VIEW, str(rrd), "--web", "--bind", "everywhere"],
                         capture_output=True, text=True, timeout=60, env=_env(tmp_path))
    assert out.returncode == 2 and "must be an IP address" in out.stderr
    out = subprocess.run([*VIEW, str(rrd), "--web", "--bind", "192.0.2.1"],  # not this host's
                         capture_output=True, text=True, timeout=60, env=_env(tmp_path))
    assert out.returncode == 1 and "Traceback" not in out.stderr
    assert out.stderr.splitlines() == [out.stderr.strip()] and "192.0.2.1" in out.stderr


# --- the web viewer, for real ---------------------------------------------------------------------


@needs_rerun
@pytest.mark.parametrize("option", ["--port", "--grpc-port"])
def test_a_port_given_and_taken_is_one_line_naming_it(rrd, tmp_path, option):
    port = free_port()
    with _held(port):
        out = subprocess.run([*VIEW, str(rrd), "--web", option, str(port)], capture_output=True,
                             text=True, timeout=120, env=_env(tmp_path))
    assert out.returncode == 1
    assert out.stdout == ""  # no URL pointing at the other server
    assert len(out.stderr.splitlines()) == 1 and "Traceback" not in out.stderr
    assert f"port {port} " in out.stderr and option in out.stderr and "in use" in out.stderr


@needs_rerun
def test_web_default_port_taken_picks_a_free_one_and_says_so(rrd, tmp_path):
    with _held(DEFAULT_WEB_PORT):
        proc = _start([*VIEW, str(rrd), "--web"], _env(tmp_path), stdout=subprocess.PIPE,
                      stderr=subprocess.PIPE)
        try:
            line = _readline(proc, 90)
            m = re.fullmatch(r"web viewer: http://127\.0\.0\.1:(\d+)/\?url=rerun%2Bhttp%3A%2F%2F"
                             r"127\.0\.0\.1%3A(\d+)%2Fproxy  \(Ctrl-C to stop; port 9090 was "
                             r"taken\)\n", line)
            assert m, line
            web, grpc = int(m[1]), int(m[2])
            assert web != DEFAULT_WEB_PORT
            # The address printed is this viewer's, serving now, on loopback only.
            with urllib.request.urlopen(f"http://127.0.0.1:{web}/", timeout=30) as page:
                assert page.status == 200 and b"<html" in page.read().lower()
            assert _listening(web) == ["127.0.0.1"] and _listening(grpc) == ["127.0.0.1"]
        finally:
            _stop(proc)
    out, err = proc.communicate()
    assert proc.returncode == 0 and out == "" and err == ""
    deadline = time.monotonic() + 10  # its servers end with it
    while _listening(web) or _listening(grpc):
        assert time.monotonic() < deadline, "the viewer outlived imucal-view"
        time.sleep(0.2)


# --- the native viewer, headless under Xvfb -------------------------------------------------------


def _display_wrapper() -> list[str]:
    if shutil.which("xvfb-run"):
        # Without the Composite extension: no 32-bit visual, so the window draws with Mesa's
        # software renderer and imucal-view opens it (viewer/native_check.py).
        return ["xvfb-run", "-a", "-s", "-screen 0 1280x800x24 -extension Composite"]
    if os.environ.get("DISPLAY"):
        return []
    need("needs a display or Xvfb: install the Debian package xvfb")
    return []


@pytest.mark.viewer
@needs_rerun
@pytest.mark.parametrize("verbose", [False, True])
def test_native_viewer_is_quiet_and_listens_on_loopback(rrd, tmp_path, verbose):
    wrapper = _display_wrapper()
    need(vulkan_missing())
    env = _env(tmp_path)
    port = free_port()
    out, err = tmp_path / "out", tmp_path / "err"
    view = " ".join(map(repr, [*VIEW, str(rrd), "--grpc-port", str(port)]
                        + (["-v"] if verbose else [])))
    # The shell's own output stays apart from imucal-view's, which goes to the two files.
    proc = _start([*wrapper, "sh", "-c", f"exec {view} > {out} 2> {err}"], env,
                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 90
        while not _listening(port):
            assert proc.poll() is None, err.read_text()
            assert time.monotonic() < deadline, "the viewer never started"
            time.sleep(0.5)
        assert _listening(port) == ["127.0.0.1"]
        time.sleep(4)  # it has drawn and logged by now
        assert proc.poll() is None
    finally:
        _stop(proc)
    # rerun's first run here: its config was written, and with it the analytics notice (not
    # where CI is set: rerun then skips its analytics, notice and config included)
    first_run = "CI" not in os.environ
    assert (tmp_path / "home" / ".config" / "rerun" / "analytics.json").exists() == first_run
    if verbose:
        assert f"Listening for gRPC connections on 127.0.0.1:{port}" in err.read_text()
        assert ("Welcome to Rerun" in err.read_text()) == first_run
    else:
        assert out.read_text() == "" and err.read_text() == ""


# --- version and completion -----------------------------------------------------------------------


def test_version_is_the_package_metadatas():
    text = (ROOT / "pyproject.toml").read_text()
    declared = re.search(r'^version = "([^"]+)"', text, re.M)[1]
    assert imucal.__version__ == version(imucal.DISTRIBUTION) == declared
    for cmd, prog in ((VIEW, "imucal-view"), (IMUCAL, "imucal")):
        out = subprocess.run([*cmd, "--version"], capture_output=True, text=True, timeout=60)
        assert out.returncode == 0 and out.stderr == ""
        assert out.stdout == f"{prog} {imucal.__version__}\n"


@pytest.mark.skipif(shutil.which("bash") is None, reason="bash is not installed")
def test_shell_completion_for_both_commands(tmp_path):
    bindir = tmp_path / "bin"
    bindir.mkdir()
    for name, cmd in (("imucal", IMUCAL), ("imucal-view", VIEW)):
        wrapper = bindir / name
        wrapper.write_text("#!/bin/sh\nexec " + " ".join(map(repr, cmd)) + ' "$@"\n')
        wrapper.chmod(0o755)
    env = _env(tmp_path, PATH=f"{bindir}:{os.environ['PATH']}", SHELL="/bin/bash")
    # What a person's bash does on TAB, with the script the command shows.
    script = """
        eval "$(imucal-view --show-completion bash)"
        COMP_WORDS=(imucal-view s.rrd --grpc); COMP_CWORD=2
        _imucal_view_completion imucal-view; echo "view: ${COMPREPLY[*]}"
        eval "$(imucal --show-completion bash)"
        COMP_WORDS=(imucal cal); COMP_CWORD=1
        _imucal_completion imucal; echo "imucal: ${COMPREPLY[*]}"
        COMP_WORDS=(imucal view s.rrd --bi); COMP_CWORD=3
        _imucal_completion imucal; echo "imucal view: ${COMPREPLY[*]}"
    """
    out = subprocess.run(["bash", "-c", script], capture_output=True, text=True, timeout=120,
                         env=env)
    assert out.returncode == 0, out.stderr
    assert out.stdout.splitlines() == ["view: --grpc-port", "imucal: calibrate",
                                       "imucal view: --bind"]
    for name in ("imucal", "imucal-view"):
        out = subprocess.run([name, "--install-completion"], capture_output=True, text=True,
                             timeout=60, env=env)
        assert out.returncode == 0, out.stderr
        installed = tmp_path / "home" / ".bash_completions" / f"{name}.sh"
        assert installed.exists()
        assert str(installed) in (tmp_path / "home" / ".bashrc").read_text()
