"""A session sent as a device sends it (``imucal synth ... --stream``): a header line, then one
line per sample (``t,ax,ay,az,gx,gy,gz``, numbers that round-trip), paced in real time or
``speed`` times faster, to standard output, to one TCP client (this side listens, as a device's
server does) or as UDP datagrams of whole lines.
"""

from __future__ import annotations

import io
import socket
import sys
import time
from collections.abc import Callable

import numpy as np

from imucal.errors import ImucalError
from imucal.session import Session

TICK_S = 0.01  # lines due are sent every 10 ms
DATAGRAM = 1400  # bytes of whole lines per UDP datagram: under an Ethernet MTU
ACCEPT_S = 30.0  # how long a TCP stream waits for its client


FORMATS = ("lines", "motioncal")
# MotionCal's "Raw:" counts (imucal.capture.lines.MOTIONCAL): 8192 per g, 16 per deg/s.
MOTIONCAL_PER_G, MOTIONCAL_PER_DEG_S = 8192.0, 16.0


def session_lines(session: Session, fmt: str = "lines") -> tuple[str | None, list[str]]:
    """The header (None for MotionCal's lines, which have none) and the sample lines (the
    gyroscope at the accelerometer's times): ``t,ax,ay,az,gx,gy,gz`` numbers that round-trip,
    or MotionCal's ``Raw:`` integer counts (no magnetometer here: zeros)."""
    if not session.has_gyro or not np.array_equal(session.t_acc, session.t_gyro):
        raise ImucalError("a stream carries the gyroscope at the accelerometer's times",
                          source="--stream")
    buf = io.StringIO()
    if fmt == "motioncal":
        if session.acc_unit != "g" or session.gyro_unit != "rad/s":
            raise ImucalError("MotionCal's lines are made from g and rad/s", source="--format")
        counts = np.column_stack([session.acc * MOTIONCAL_PER_G,
                                  np.rad2deg(session.gyro) * MOTIONCAL_PER_DEG_S,
                                  np.zeros((len(session.acc), 3))])
        np.savetxt(buf, np.round(counts), fmt="%d", delimiter=",")
        return None, ["Raw:" + line for line in buf.getvalue().splitlines()]
    np.savetxt(buf, np.column_stack([session.t_acc, session.acc, session.gyro]), fmt="%.17g",
               delimiter=",")
    return "t,ax,ay,az,gx,gy,gz", buf.getvalue().splitlines()


def paced(t: np.ndarray, lines: list[str], speed: float | None, send: Callable[[list[str]], None]
          ) -> None:
    """Call ``send`` with the lines due every tick: sample i at ``t[i] / speed`` seconds from
    the first (all at once when ``speed`` is None)."""
    if speed is None:
        send(lines)
        return
    start = time.monotonic()
    due_at = (t - t[0]) / speed
    i = 0
    while i < len(lines):
        j = int(np.searchsorted(due_at, time.monotonic() - start, side="right"))
        if j > i:
            send(lines[i:j])
            i = j
        time.sleep(TICK_S)


def stream_session(session: Session, target: str, speed: float | None, fmt: str = "lines",
                   on_ready: Callable[[str], None] | None = None) -> None:
    """Send ``session`` to ``target``: ``-``, ``tcp://HOST:PORT`` or ``udp://HOST:PORT``."""
    header, lines = session_lines(session, fmt)
    head = [] if header is None else [header]
    t = session.t_acc
    if target == "-":
        out = sys.stdout.buffer

        def send(chunk: list[str]) -> None:
            if not chunk:
                return
            out.write(("\n".join(chunk) + "\n").encode())
            out.flush()

        send(head)
        paced(t, lines, speed, send)
        return
    scheme, _, rest = target.partition("://")
    host, _, port = rest.rpartition(":")
    if scheme not in ("tcp", "udp") or not port.isdigit():
        raise ImucalError("expected -, tcp://HOST:PORT or udp://HOST:PORT", source=target)
    if scheme == "tcp":
        with socket.create_server((host or "127.0.0.1", int(port))) as server:
            if on_ready is not None:
                on_ready(f"tcp://{host}:{server.getsockname()[1]}")
            server.settimeout(ACCEPT_S)
            try:
                conn, _ = server.accept()
            except TimeoutError as e:
                raise ImucalError(f"no client connected in {ACCEPT_S:g} s", source=target) from e
            with conn:
                def send_tcp(chunk: list[str]) -> None:
                    conn.sendall(("\n".join(chunk) + "\n").encode())

                send_tcp(head)
                paced(t, lines, speed, send_tcp)
        return
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        address = (host or "127.0.0.1", int(port))

        def send_udp(chunk: list[str]) -> None:
            packet: list[str] = []
            size = 0
            for line in chunk:  # whole lines per datagram (a loop over the tick's lines)
                if packet and size + len(line) + 1 > DATAGRAM:
                    sock.sendto(("\n".join(packet) + "\n").encode(), address)
                    packet, size = [], 0
                packet.append(line)
                size += len(line) + 1
            if packet:
                sock.sendto(("\n".join(packet) + "\n").encode(), address)

        send_udp(head)
        paced(t, lines, speed, send_udp)
