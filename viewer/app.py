"""``imucal-view SESSION|RUN.rrd [--save FILE.rrd] [--web] [--port N]``: see a calibration run.

A session file is loaded (:func:`imucal.load_session`), calibrated and recorded; an ``.rrd``
(recognised by its extension or its first bytes) is shown as it is.

- ``--save FILE.rrd``: write the recording and open nothing (headless, for scripts and CI).
- ``--web``: serve the web viewer on 127.0.0.1 (port ``--port``, default 9090) and print its
  URL; runs until Ctrl-C.
- otherwise the native viewer opens the recording. Where there is no display (neither
  ``DISPLAY`` nor ``WAYLAND_DISPLAY`` is set) it says so in one line and writes
  ``<session stem>.rrd`` in the current directory instead (``<stem>-1.rrd``, ``-2`` ... when
  that name is taken: a name the user did not give never replaces a file); it never waits
  for a window.

It is ``imucal view`` under its own name: the same options (``--gyro`` for a two-file session,
units, every calibration setting) and the same one-line errors with exit code 1.
``import rerun`` (slow) happens only when a recording is written.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING
from urllib.parse import quote

from imucal.errors import ImucalError
from imucal.io.atomic import Transaction

if TYPE_CHECKING:
    from imucal.result import Result

RRD_MAGIC = b"RRF"  # every .rrd starts with RRF0, RRF1 or RRF2


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


def free_port(host: str = "127.0.0.1") -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def web_url(web_port: int, grpc_port: int, host: str = "127.0.0.1") -> str:
    """The address that opens the web viewer on the recording served over gRPC."""
    proxy = f"rerun+http://{host}:{grpc_port}/proxy"
    return f"http://{host}:{web_port}/?url={quote(proxy, safe='')}"


def web_command(rerun: str, rrd: str | os.PathLike, web_port: int, grpc_port: int) -> list[str]:
    """``rerun`` serving ``rrd`` to a web viewer, both servers on loopback only."""
    return [rerun, "--web-viewer", "--bind", "127.0.0.1", "--web-viewer-port", str(web_port),
            "--port", str(grpc_port), str(rrd)]


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


def _run(cmd: list[str]) -> int:
    """Run a viewer in its own process group until it exits, or until Ctrl-C or SIGTERM reach
    us; then end its group (the ``rerun`` launcher runs the real binary as a child)."""
    proc = subprocess.Popen(cmd, start_new_session=True)

    def interrupt(signum, frame):
        raise KeyboardInterrupt

    previous = {}
    with contextlib.suppress(ValueError):  # signal handlers only from the main thread
        for sig in (signal.SIGTERM, signal.SIGHUP):
            previous[sig] = signal.signal(sig, interrupt)
    try:
        return proc.wait()
    except KeyboardInterrupt:
        return 0
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        _end_group(proc)


def _end_group(proc: subprocess.Popen) -> None:
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, signal.SIGTERM)
    try:
        proc.wait(timeout=5)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def view(target: str, *, save: str | None = None, web: bool = False, port: int = 9090,
         load_options: dict | None = None, **calibrate_kwargs) -> int:
    """Record and/or show ``target`` (a session or an ``.rrd``); returns the exit code.

    ``load_options`` go to :func:`imucal.load_session`, ``calibrate_kwargs`` to
    :func:`imucal.calibrate` (settings such as ``lam`` or ``single_segment``).
    """
    try:
        return show(target, save=save, web=web, port=port, load_options=load_options,
                    **calibrate_kwargs)
    except ImucalError as e:
        print(f"imucal-view: {e}", file=sys.stderr)
        return 1


def show(target: str, *, save: str | None = None, web: bool = False, port: int = 9090,
         load_options: dict | None = None, **calibrate_kwargs) -> int:
    """:func:`view` raising :class:`~imucal.errors.ImucalError` instead of printing it (for the
    command line, which reports every error the same way)."""
    src = Path(target)
    if not src.is_file():
        raise ImucalError("no such file", source=str(target))
    rrd = is_rrd(src)

    if save is not None:
        if rrd:
            _copy_recording(src, save)
        else:
            record(src, save, load_options, **calibrate_kwargs)
        print(f"wrote {save}")
        return 0

    if not web and not has_display():
        if rrd:
            raise ImucalError("no display (neither DISPLAY nor WAYLAND_DISPLAY is set): cannot "
                              "open it here; try --web, or open it where there is a display",
                              source=str(src))
        out = free_name(Path.cwd(), src.stem)
        record(src, out, load_options, exclusive=True, **calibrate_kwargs)
        print(f"no display (neither DISPLAY nor WAYLAND_DISPLAY is set): wrote {out} instead; "
              "open it where there is a display, or use --web")
        return 0

    rerun = rerun_executable()
    if rerun is None:
        raise ImucalError("the 'rerun' viewer is not installed (pip install rerun-sdk)",
                          source="viewer")
    with tempfile.TemporaryDirectory(prefix="imucal-view-") as tmp:
        shown = src
        if not rrd:
            shown = Path(tmp) / f"{src.stem}.rrd"
            record(src, shown, load_options, **calibrate_kwargs)
        if web:
            grpc = free_port()
            print(f"web viewer: {web_url(port, grpc)}  (Ctrl-C to stop)", flush=True)
            return _run(web_command(rerun, shown, port, grpc))
        return _run([rerun, str(shown)])
