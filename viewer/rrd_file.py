"""Writing a recording to a file: bounded in time and interruptible.

Rerun's file sink (``RecordingStream.save``) writes from a thread of its own. On a full disk it
logs an error and its ``flush``/``disconnect`` then wait forever, deaf to Ctrl-C and SIGTERM
(measured with rerun-sdk 0.41.0 on a 200 kB tmpfs: only SIGKILL ended the run). So the sink
here writes into a pipe, never to the disk: a Python thread (:class:`_Pump`) copies the pipe
into the file and, once a write has failed, keeps reading and drops the rest, so Rerun's
writer never waits. The failure comes back as the ``OSError`` it was, after the sink is
closed. Every wait on Rerun is short (``_WAIT_S``): a pending Ctrl-C is acted on between two
of them, and an encoder that has not finished within ``timeout`` seconds is a one-line error.

The file is the one ``save`` writes (layout first, then the recording, then the footer):
a viewer that finds the recording before its layout makes up a layout of its own.
"""

from __future__ import annotations

import contextlib
import os
import threading
import time
from collections.abc import Iterator
from typing import BinaryIO

from imucal.errors import ImucalError

FLUSH_TIMEOUT_S = 120.0  # encoding runs at ~50 MB/s here (22 MB through the pipe in 0.45 s)
_WAIT_S = 0.2  # one wait on Rerun's encoder: how late a Ctrl-C may be acted on


def flush(rec, timeout: float = FLUSH_TIMEOUT_S) -> None:
    """Wait until ``rec`` has handed everything logged to its sink, in short waits (between
    them Python acts on a pending signal); :class:`ImucalError` after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            rec.flush(timeout_sec=min(_WAIT_S, max(deadline - time.monotonic(), 0.0)))
            return
        except RuntimeError as e:
            if "timed out" not in str(e).lower():
                raise
        if time.monotonic() >= deadline:
            raise ImucalError(f"the recording was not encoded within {timeout:g} s; nothing "
                              "was written", source="recording")


class _Pump(threading.Thread):
    """Pipe to file until the pipe's writer closes it; after a failed write (or ``drop``),
    read on and discard."""

    def __init__(self, fd: int, file: BinaryIO) -> None:
        super().__init__(name="imucal-rrd-pump", daemon=True)
        self.fd, self.file = fd, file
        self.error: BaseException | None = None
        self.drop = False

    def run(self) -> None:
        try:
            while chunk := os.read(self.fd, 1 << 20):
                if self.error is None and not self.drop:
                    try:
                        self.file.write(chunk)
                    except BaseException as e:  # noqa: BLE001 -- reported by rrd_sink
                        self.error = e
        finally:
            os.close(self.fd)


def _fd_dir() -> str:
    """Where a process names its own open descriptors (the sink opens the pipe by name)."""
    for base in ("/dev/fd", "/proc/self/fd"):
        if os.path.isdir(base):
            return base
    raise ImucalError("cannot write a recording here: the system has neither /dev/fd nor "
                      "/proc/self/fd", source="recording")


@contextlib.contextmanager
def rrd_sink(rec, file: BinaryIO, default_blueprint=None,
             timeout: float = FLUSH_TIMEOUT_S) -> Iterator[None]:
    """Inside the block, what is logged to ``rec`` goes to ``file`` (with the layout
    ``default_blueprint``); on leaving it the recording is complete in ``file`` (footer
    included) or an error is raised: the write's ``OSError``, or :class:`ImucalError` for an
    encoder slower than ``timeout``."""
    base = _fd_dir()
    r, w = os.pipe()
    pump = _Pump(r, file)
    pump.start()
    try:
        rec.save(f"{base}/{w}", default_blueprint=default_blueprint)
    finally:
        os.close(w)  # the sink opened a descriptor of its own
    done = False
    try:
        yield
        flush(rec, timeout)
        done = True
    finally:
        pump.drop = not done
        # Closing the sink writes what is left (the footer) into the pipe, which the pump
        # reads: this returns, and the pump then sees the pipe's end.
        rec.disconnect()
        pump.join()
    if pump.error is not None:
        raise pump.error
    file.flush()
