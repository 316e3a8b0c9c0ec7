"""``imucal-view SESSION|RUN.rrd [--save FILE.rrd] [--web] [--port N] [--grpc-port N]
[--bind ADDR] [-v]``: see a calibration run.

A session file is loaded (:func:`imucal.load_session`), calibrated and recorded; an ``.rrd``
(recognised by its extension or its first bytes) is shown as it is.

- ``--save FILE.rrd``: write the recording and open nothing (headless, for scripts and CI).
- ``--web``: serve the web viewer (port ``--port``: 9090, or a free one when 9090 is taken)
  and print its URL once it answers; runs until Ctrl-C.
- otherwise the native viewer opens the recording. Where there is no display (neither
  ``DISPLAY`` nor ``WAYLAND_DISPLAY`` is set) it says so in one line and writes
  ``<session stem>.rrd`` in the current directory instead (``<stem>-1.rrd``, ``-2`` ... when
  that name is taken: a name the user did not give never replaces a file); it never waits
  for a window.

Every server the viewer starts listens on 127.0.0.1 unless ``--bind`` says otherwise (rerun's
own default is every interface), and its gRPC server on a free port unless ``--grpc-port``
names one (rerun's default 9876 would hand the recording to another viewer already there). A
port the user names is checked first: taken, it is a one-line error naming it. The viewer's
own log (a dozen INFO/WARN lines, rerun's first-run analytics notice) goes to a file that is
read only when the viewer fails, to say why in one line; ``-v`` shows it on the terminal.

It is ``imucal view`` under its own name: the same options (``--gyro`` for a two-file session,
units, every calibration setting) and the same one-line errors with exit code 1.
``import rerun`` (slow) happens only when a recording is written.
"""

from __future__ import annotations

import contextlib
import errno
import functools
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING
from urllib.parse import quote

from imucal.errors import ImucalError
from imucal.io.atomic import Transaction

from .native_check import black_window_reason

if TYPE_CHECKING:
    from imucal.result import Result

RRD_MAGIC = b"RRF"  # every .rrd starts with RRF0, RRF1 or RRF2
LOOPBACK = "127.0.0.1"
DEFAULT_WEB_PORT = 9090  # rerun's own default for the web viewer


def is_rrd(path: str | os.PathLike) -> bool:
    """True for a Rerun recording: extension ``.rrd`` or the RRF magic bytes."""
    p = Path(path)
    if p.suffix.lower() == ".rrd":
        return True
    try:
        with open(p, "rb") as f:
            return f.read(3) == RRD_MAGIC
    except OSError:
        return False


def rerun_executable() -> str | None:
    """The ``rerun`` launcher of this environment (beside the Python running us), else PATH's."""
    here = Path(sys.executable).parent / "rerun"
    if here.exists():
        return str(here)
    return shutil.which("rerun")


def has_display(env: os._Environ | dict | None = None) -> bool:
    env = os.environ if env is None else env
    return bool(env.get("DISPLAY") or env.get("WAYLAND_DISPLAY"))


def free_port(host: str = LOOPBACK) -> int:
    """A port nothing listens on now (the kernel's pick)."""
    with socket.socket(_family(host)) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def _family(host: str) -> socket.AddressFamily:
    return socket.AF_INET6 if ":" in host else socket.AF_INET


def port_taken(port: int, host: str = LOOPBACK) -> bool:
    """True when a server already holds ``port`` on ``host`` (or on every interface).

    Checked by binding as the viewer's servers will (with SO_REUSEADDR, as Rust's listeners
    do), so a port left in TIME_WAIT by a stopped viewer counts as free, as it is for them."""
    with socket.socket(_family(host)) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError as e:
            if e.errno == errno.EADDRINUSE:
                return True
            raise
    return False


def choose_port(requested: int | None, default: int | None, host: str, option: str) -> int:
    """The port to serve on: the user's (``requested``), which must be free (else a one-line
    error naming it); otherwise ``default`` if free, else a free one (``default=None``: always
    a free one, so the viewer never joins another one already listening there)."""
    try:
        if requested is not None:
            if port_taken(requested, host):
                raise ImucalError(f"port {requested} on {host} is already in use (another "
                                  "viewer or server?): choose another, or leave the option out "
                                  "to take a free one", source=option)
            return requested
        if default is not None and not port_taken(default, host):
            return default
        return free_port(host)
    except OSError as e:  # not an address of this machine, a privileged port, ...
        port = requested if requested is not None else default
        raise ImucalError(f"cannot listen on {host} port {port}: {e.strerror or e}",
                          source=option) from None


def url_host(bind: str) -> str:
    """Where a browser on this machine reaches a server bound to ``bind``."""
    if bind in ("0.0.0.0", "::"):
        return LOOPBACK
    return f"[{bind}]" if ":" in bind else bind


def web_url(web_port: int, grpc_port: int, host: str = LOOPBACK) -> str:
    """The address that opens the web viewer on the recording served over gRPC."""
    proxy = f"rerun+http://{host}:{grpc_port}/proxy"
    return f"http://{host}:{web_port}/?url={quote(proxy, safe='')}"


def web_command(rerun: str, rrd: str | os.PathLike, web_port: int, grpc_port: int,
                bind: str = LOOPBACK) -> list[str]:
    """``rerun`` serving ``rrd`` to a web viewer, both servers on ``bind`` (loopback unless the
    user asked otherwise)."""
    return [rerun, "--web-viewer", "--bind", bind, "--web-viewer-port", str(web_port),
            "--port", str(grpc_port), str(rrd)]


def native_command(rerun: str, rrd: str | os.PathLike, grpc_port: int,
                   bind: str = LOOPBACK) -> list[str]:
    """``rerun`` opening ``rrd`` in the native viewer. Its own gRPC server (for SDKs that log to
    it) listens on ``bind`` (loopback unless asked: rerun's default is every interface) and on
    ``grpc_port``: a port chosen free, so the recording never goes to another viewer that
    already listens on rerun's default 9876 instead of opening here."""
    return [rerun, "--bind", bind, "--port", str(grpc_port), str(rrd)]


def viewer_env(verbose: bool, env: Mapping[str, str] | None = None) -> dict[str, str]:
    """The viewer's environment: quiet logs (warnings and errors only, for the one-line error)
    unless ``verbose`` or the user set ``RUST_LOG``; plain text (no colour codes) in the log."""
    out = dict(os.environ if env is None else env)
    if not verbose:
        out.setdefault("RUST_LOG", "warn")
        out.setdefault("NO_COLOR", "1")
    return out


_ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")
_GPU_WORDS = ("render context", "gpu", "graphics driver", "vulkan", "adapter", "wgpu")


def viewer_error(log: str, returncode: int) -> str:
    """One line saying why the viewer stopped, from its log: its final ``Error:`` line, else
    its last ``ERROR`` record, else the exit code; with what to install where the cause is a
    missing renderer."""
    lines = [_ANSI.sub("", line).strip() for line in log.splitlines()]
    lines = [line for line in lines if line]
    why = next((line.removeprefix("Error:").strip() for line in reversed(lines)
                if line.startswith("Error:")), None)
    if why is None:
        why = next((line.split(" ERROR ", 1)[1].strip() for line in reversed(lines)
                    if " ERROR " in line), None)
    message = f"the viewer stopped (exit code {returncode})"
    if why:
        message += f": {why[:300]}"
    if why and any(word in why.lower() for word in _GPU_WORDS):
        message += ("; the native viewer needs a GPU or a software Vulkan renderer (Debian/"
                    "Ubuntu: apt install mesa-vulkan-drivers), or use --web")
    return message


def record(target: str | os.PathLike, out: str | os.PathLike,
           load_options: dict | None = None, *, exclusive: bool = False,
           **calibrate_kwargs) -> Result:
    """Load and calibrate a session, write its recording to ``out`` (atomically: temporary
    file, then rename; ``exclusive``: never replace a file of that name)."""
    import imucal

    from .recording import save_recording

    with Transaction([out], inputs=[target], exclusive=[out] if exclusive else []) as tx:
        session = imucal.load_session(target, **(load_options or {}))
        result = imucal.calibrate(session, **calibrate_kwargs)
        with tx.writing(out) as tmp, open(tmp, "wb") as f:
            save_recording(result, f)
        tx.commit()
    return result


def _reporting(on_result: Callable[[Result], None]) -> Callable[..., Result]:
    """:func:`record`, then ``on_result`` of what it calibrated."""
    def run(*args, **kwargs) -> Result:
        result = record(*args, **kwargs)
        on_result(result)
        return result
    return run


def free_name(directory: Path, stem: str, suffix: str = ".rrd") -> Path:
    """``stem.rrd`` in ``directory``, else the first free ``stem-1.rrd``, ``stem-2.rrd``, ...:
    the name imucal picks itself never replaces a file."""
    n = 0
    while True:
        path = directory / f"{stem}{'' if n == 0 else f'-{n}'}{suffix}"
        if not os.path.lexists(path):
            return path
        n += 1


def _copy_recording(src: Path, dst: str | os.PathLike) -> None:
    """Copy a saved recording, after checking that it is one (its RRF header): not any file
    that ends in .rrd."""
    with open(src, "rb") as f:
        head = f.read(4)
    if head[:3] != RRD_MAGIC:
        raise ImucalError("not a Rerun recording (no RRF header); nothing was copied",
                          source=str(src))
    with Transaction([dst], inputs=[src]) as tx:
        with tx.writing(dst) as tmp:
            shutil.copyfile(src, tmp)
        tx.commit()


@dataclass
class Launch:
    """How to run one viewer: its command line, environment, where its output goes (``log``:
    a file; ``None``: the user's terminal, for ``-v``) and ``ready``, called once it started
    (the web viewer's address is printed there, once its server answers)."""

    cmd: list[str]
    env: dict[str, str]
    log: Path | None = None
    ready: Callable[[subprocess.Popen], None] | None = None


def _run(launch: Launch) -> int:
    """Run a viewer in its own process group until it exits, or until Ctrl-C or SIGTERM reach
    us; then end its group (the ``rerun`` launcher runs the real binary as a child). A viewer
    that fails is one line (:func:`viewer_error`), raised as an :class:`ImucalError`."""
    out = open(launch.log, "wb") if launch.log else None  # noqa: SIM115 (closed below)
    try:
        proc = subprocess.Popen(launch.cmd, start_new_session=True, env=launch.env,
                                stdin=subprocess.DEVNULL, stdout=out,
                                stderr=subprocess.STDOUT if out else None)
    finally:
        if out is not None:
            out.close()  # the child has its own copy

    def interrupt(signum, frame):
        raise KeyboardInterrupt

    previous = {}
    with contextlib.suppress(ValueError):  # signal handlers only from the main thread
        for sig in (signal.SIGTERM, signal.SIGHUP):
            previous[sig] = signal.signal(sig, interrupt)
    try:
        if launch.ready is not None:
            launch.ready(proc)
        rc = proc.wait()
    except KeyboardInterrupt:
        return 0
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        _end_group(proc)
    if rc != 0:
        log = launch.log.read_text(errors="replace") if launch.log else ""
        raise ImucalError(viewer_error(log, rc))
    return 0


def wait_serving(proc: subprocess.Popen, host: str, port: int, timeout: float = 60.0) -> bool:
    """Wait until ``port`` accepts connections (True), or the viewer exits or ``timeout``
    passes (False)."""
    deadline = time.monotonic() + timeout
    while proc.poll() is None and time.monotonic() < deadline:
        with contextlib.suppress(OSError), socket.create_connection((host, port), timeout=1.0):
            return True
        time.sleep(0.1)
    return False


def _end_group(proc: subprocess.Popen) -> None:
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, signal.SIGTERM)
    try:
        proc.wait(timeout=5)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def view(target: str, *, save: str | None = None, web: bool = False,
         port: int | None = None, grpc_port: int | None = None, bind: str = LOOPBACK,
         verbose: bool = False, load_options: dict | None = None, **calibrate_kwargs) -> int:
    """Record and/or show ``target`` (a session or an ``.rrd``); returns the exit code.

    ``port``: the web viewer's (default 9090, else a free one), ``grpc_port``: the gRPC
    server's (default: a free one); a port given must be free. ``bind``: the servers' address
    (loopback by default). ``verbose``: the viewer's own log on the terminal.
    ``load_options`` go to :func:`imucal.load_session`, ``calibrate_kwargs`` to
    :func:`imucal.calibrate` (settings such as ``lam`` or ``single_segment``).
    """
    try:
        return show(target, save=save, web=web, port=port, grpc_port=grpc_port, bind=bind,
                    verbose=verbose, load_options=load_options, **calibrate_kwargs)
    except ImucalError as e:
        print(f"imucal-view: {e}", file=sys.stderr)
        return 1


def show(target: str, *, save: str | None = None, web: bool = False,
         port: int | None = None, grpc_port: int | None = None, bind: str = LOOPBACK,
         verbose: bool = False, load_options: dict | None = None,
         on_result: Callable[[Result], None] | None = None, **calibrate_kwargs) -> int:
    """:func:`view` raising :class:`~imucal.errors.ImucalError` instead of printing it (for the
    command line, which reports every error the same way). ``on_result`` is given a session's
    result as soon as it is calibrated (the command line prints its result line)."""
    src = Path(target)
    calibrate = record if on_result is None else _reporting(on_result)

    if not src.is_file():
        raise ImucalError("no such file", source=str(target))
    rrd = is_rrd(src)

    if save is not None:
        if rrd:
            _copy_recording(src, save)
        else:
            calibrate(src, save, load_options, **calibrate_kwargs)
        print(f"wrote {save}")
        return 0

    if not web and not has_display():
        if rrd:
            raise ImucalError("no display (neither DISPLAY nor WAYLAND_DISPLAY is set): cannot "
                              "open it here; try --web, or open it where there is a display",
                              source=str(src))
        out = free_name(Path.cwd(), src.stem)
        calibrate(src, out, load_options, exclusive=True, **calibrate_kwargs)
        print(f"no display (neither DISPLAY nor WAYLAND_DISPLAY is set): wrote {out} instead; "
              "open it where there is a display, or use --web")
        return 0

    rerun = rerun_executable()
    if rerun is None:
        raise ImucalError("the 'rerun' viewer is not installed (pip install rerun-sdk)",
                          source="viewer")
    black = None if web else black_window_reason(os.environ)
    if black is not None:  # before the (slow) calibration: a window that would stay black
        raise ImucalError(black, source="viewer")
    # The ports are checked before the (slow) calibration: a taken one fails at once.
    grpc = choose_port(grpc_port, None, bind, "--grpc-port")
    web_port = choose_port(port, DEFAULT_WEB_PORT, bind, "--port") if web else None
    with tempfile.TemporaryDirectory(prefix="imucal-view-") as tmp:
        shown = src
        if not rrd:
            shown = Path(tmp) / f"{src.stem}.rrd"
            calibrate(src, shown, load_options, **calibrate_kwargs)
        log = None if verbose else Path(tmp) / "viewer.log"
        env = viewer_env(verbose)
        if web_port is None:
            return _run(Launch(native_command(rerun, shown, grpc, bind), env, log))
        return _run(Launch(web_command(rerun, shown, web_port, grpc, bind), env, log,
                           ready=functools.partial(_announce, host=url_host(bind),
                                                   web_port=web_port, grpc_port=grpc,
                                                   asked=port)))


def _announce(proc: subprocess.Popen, *, host: str, web_port: int, grpc_port: int,
              asked: int | None) -> None:
    """Print the web viewer's address once its server answers (so it never names another
    server), saying so when the default port was taken and another was chosen."""
    if not wait_serving(proc, host.strip("[]"), web_port) and proc.poll() is not None:
        return  # it exited: its one-line error follows, not an address that answers nothing
    note = ""
    if asked is None and web_port != DEFAULT_WEB_PORT:
        note = f"; port {DEFAULT_WEB_PORT} was taken"
    print(f"web viewer: {web_url(web_port, grpc_port, host)}  (Ctrl-C to stop{note})",
          flush=True)
