"""What every capture source is: a stream of bytes read with a timeout (:class:`Source`).

Every source is read the same way: :meth:`Source.read` waits at most ``timeout`` seconds and
returns the bytes that came (``b""`` when none did), or None once the stream has ended (end of
file, the peer closed, the cable pulled: an OS error on read ends the stream, it does not lose
what was already written).

Kept apart from :mod:`imucal.capture.sources` (which opens the source a SOURCE argument names)
so that each kind of source, :mod:`imucal.capture.mavlink` among them, builds on this one and
the opener sits above them all: imports run one way.
"""

from __future__ import annotations

import os
import select

CHUNK = 1 << 16  # bytes read at once: 64 KB holds ~0.6 s of 1 kHz lines of seven numbers


class Source:
    """A stream of bytes read with a timeout; ``describe`` names it in messages."""

    describe = "the source"
    hint = "the format and the columns"  # what to check when nothing valid arrives

    def fileno(self) -> int:
        raise NotImplementedError

    def _read_ready(self) -> bytes:
        """Bytes from a descriptor select() found ready; b"" means the stream ended."""
        return os.read(self.fileno(), CHUNK)

    def read(self, timeout: float) -> bytes | None:
        try:
            ready, _, _ = select.select([self.fileno()], [], [], max(timeout, 0.0))
            if not ready:
                return b""
            data = self._read_ready()
        except (OSError, ValueError):  # a pulled cable, a reset connection, a closed port
            return None
        return data if data else None

    def close(self) -> None:
        pass
