"""The session file, written as samples arrive: ``DIR/session.csv``, a header line and every
valid line as received (commas between the fields).

Rows wait in memory and are written whole, at least every ``FLUSH_S`` seconds, with one
``os.write`` of complete lines: a capture killed with SIGKILL leaves every sample up to the last
write, and no half row unless the disk filled mid-write (which the table loader reads as a cut
last line). A full disk stops the writing, not the capture's end: what is written stays readable.
"""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path

from imucal.errors import ImucalError

FLUSH_S = 0.5  # the longest a received sample waits before it is in the file (issue 25)
SESSION_NAME = "session.csv"


class SessionWriter:
    """Append-only writer of the capture's session file; ``lock`` is held while a row batch
    is written, so a reader of the file (the running calibration) sees only whole rows."""

    def __init__(self, directory: str | os.PathLike, header: list[str] | None = None):
        self.directory = Path(directory)
        self.path = self.directory / SESSION_NAME
        self.directory.mkdir(parents=True, exist_ok=True)
        try:
            # O_EXCL: a capture never replaces a session recorded before.
            self.fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        except FileExistsError as e:
            raise ImucalError("a capture is already there; give another --out directory",
                              source=str(self.path)) from e
        self.lock = threading.Lock()
        self.pending: list[str] = []
        self.rows = 0  # rows in the file
        self.last_write = time.monotonic()
        self.error: str | None = None  # the OS error that stopped the writing (a full disk)
        if header is not None:
            self.start(header)

    def start(self, header: list[str]) -> None:
        self._write(",".join(header) + "\n")

    def add(self, lines: list[str]) -> None:
        self.pending.extend(lines)

    def due(self, now: float) -> bool:
        return bool(self.pending) and now - self.last_write >= FLUSH_S

    def flush(self, wait: bool = True) -> bool:
        """Write what waits; False when a reader holds the file and ``wait`` is False."""
        if not self.pending:
            return True
        if not self.lock.acquire(blocking=wait):
            return False
        try:
            # Taken out before the write: a Ctrl-C during it can never write a row twice.
            rows, self.pending = self.pending, []
            self._write("\n".join(rows) + "\n")
            if self.error is None:
                self.rows += len(rows)
        finally:
            self.lock.release()
        return True

    def _write(self, text: str) -> None:
        self.last_write = time.monotonic()
        if self.error is not None:
            return
        data = text.encode("ascii", errors="replace")
        try:
            while data:
                done = os.write(self.fd, data)
                data = data[done:]
        except OSError as e:  # ENOSPC, EIO: keep what is written, say it at the end
            self.error = f"{self.path}: {e.strerror or e}"

    def close(self) -> None:
        self.flush()
        try:
            os.fsync(self.fd)  # the last rows survive a power cut, not only a crash
        except OSError:
            pass
        os.close(self.fd)
