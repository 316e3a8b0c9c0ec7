"""Where a capture's bytes come from: ``-`` (standard input), ``tcp://HOST:PORT`` (connect),
``udp://[HOST]:PORT`` (listen), ``serial:/dev/ttyX?baud=N`` (pyserial, imported only then),
``mavlink:...`` (pymavlink, :mod:`imucal.capture.mavlink`).

Every source is read the same way (:class:`imucal.capture.byte_source.Source`, which each one
here builds on): :meth:`~imucal.capture.byte_source.Source.read` waits at most ``timeout``
seconds and returns the bytes that came (``b""`` when none did), or None once the stream has
ended. :func:`open_source` opens the one a SOURCE argument names.
"""

from __future__ import annotations

import socket
import time
from urllib.parse import parse_qs, urlsplit

from imucal.capture.byte_source import CHUNK, Source
from imucal.errors import ImucalError

UDP_BUFFER = 1 << 22  # the kernel's receive buffer asked for: a pause loses no datagram


class FdSource(Source):
    """Standard input, or any open file descriptor (a pipe, a pseudo-terminal in the tests)."""

    def __init__(self, fd: int, describe: str = "standard input"):
        self.fd, self.describe = fd, describe

    def fileno(self) -> int:
        return self.fd


class TcpSource(Source):
    hint = "the host and port, and the format and the columns"

    def __init__(self, host: str, port: int, connect_timeout: float = 5.0):
        self.describe = f"tcp://{host}:{port}"
        # A device (or a replay) that is still starting refuses at first: retry until the
        # timeout, then say why.
        deadline = time.monotonic() + connect_timeout
        while True:
            try:
                self.sock = socket.create_connection((host, port), timeout=connect_timeout)
                break
            except OSError as e:
                if time.monotonic() >= deadline:
                    raise ImucalError(f"cannot connect: {e.strerror or e}",
                                      source=self.describe) from e
                time.sleep(0.1)
        self.sock.setblocking(False)

    def fileno(self) -> int:
        return self.sock.fileno()

    def _read_ready(self) -> bytes:
        return self.sock.recv(CHUNK)

    def close(self) -> None:
        self.sock.close()


class UdpSource(Source):
    """Datagrams of lines; each datagram ends its last line (a sender that leaves the newline
    off still gives whole lines). UDP has no end: the capture stops by its own rule."""

    hint = "the port, that the sender sends to this host, and the format and the columns"

    def __init__(self, host: str, port: int):
        self.describe = f"udp://{host}:{port}"
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, UDP_BUFFER)
            self.sock.bind((host or "0.0.0.0", port))
        except OSError as e:
            self.sock.close()
            raise ImucalError(f"cannot listen: {e.strerror or e}", source=self.describe) from e
        self.sock.setblocking(False)

    @property
    def port(self) -> int:
        return int(self.sock.getsockname()[1])

    def fileno(self) -> int:
        return self.sock.fileno()

    def _read_ready(self) -> bytes:
        out = []
        while True:  # every datagram waiting, in one read
            try:
                data = self.sock.recv(CHUNK)
            except BlockingIOError:
                break
            out.append(data if data.endswith(b"\n") else data + b"\n")
        return b"".join(out) or b"\n"  # an empty datagram is no end of stream

    def close(self) -> None:
        self.sock.close()


class SerialSource(Source):
    hint = "the baud rate (?baud=N), the format and the columns"

    def __init__(self, path: str, baud: int):
        import serial  # pyserial: only a serial capture needs it

        self.describe = f"serial:{path}?baud={baud}"
        try:
            self.port = serial.Serial(path, baudrate=baud, timeout=0)
        except (serial.SerialException, OSError, ValueError) as e:
            raise ImucalError(f"cannot open the serial port: {e}", source=self.describe) from e

    def fileno(self) -> int:
        return self.port.fileno()

    def _read_ready(self) -> bytes:
        # select() said readable: pyserial's read of at least one byte returns what is there;
        # a readable port that gives nothing is a device gone (pyserial raises for that).
        return self.port.read(max(1, self.port.in_waiting))

    def close(self) -> None:
        self.port.close()


def open_source(spec: str) -> Source:
    """The source a capture's SOURCE argument names (see the module's docstring)."""
    if spec == "-":
        return FdSource(0)
    if spec.startswith("mavlink:"):
        from imucal.capture.mavlink import MavlinkSource

        return MavlinkSource(spec)
    if spec.startswith("serial:"):
        parts = urlsplit(spec[len("serial:"):])
        query = parse_qs(parts.query)
        try:
            baud = int(query.get("baud", ["115200"])[0])
        except ValueError as e:
            raise ImucalError("baud must be a whole number, e.g. ?baud=115200",
                              source=spec, field="baud") from e
        if not parts.path:
            raise ImucalError("expected serial:/dev/ttyX?baud=N", source=spec)
        return SerialSource(parts.path, baud)
    for scheme, cls in (("tcp://", TcpSource), ("udp://", UdpSource)):
        if spec.startswith(scheme):
            host, port = _host_port(spec, scheme)
            if cls is TcpSource and not host:
                raise ImucalError("expected tcp://HOST:PORT (a host to connect to)", source=spec)
            return cls(host, port)
    raise ImucalError("unknown source: expected -, tcp://HOST:PORT, udp://[HOST]:PORT, "
                      "serial:/dev/ttyX?baud=N, mavlink:udp:HOST:PORT or mavlink:/dev/ttyX",
                      source=spec)


def _host_port(spec: str, scheme: str) -> tuple[str, int]:
    rest = spec[len(scheme):]
    host, sep, port = rest.rpartition(":")
    if not sep or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ImucalError(f"expected {scheme}HOST:PORT with a port number", source=spec,
                          field="port")
    return host.strip("[]"), int(port)
