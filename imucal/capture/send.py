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
from imucal.session import STANDARD_GRAVITY, Session

TICK_S = 0.01  # lines due are sent every 10 ms
DATAGRAM = 1400  # bytes of whole lines per UDP datagram: under an Ethernet MTU
ACCEPT_S = 30.0  # how long a TCP stream waits for its client


FORMATS = ("lines", "motioncal", "mavlink")
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


def mavlink_frames(session: Session) -> list[bytes]:
    """One ``HIGHRES_IMU`` MAVLink 2 frame per sample (m/s^2, rad/s, µs), by pymavlink's own
    encoder: a frame per message is MAVLink's nature, so this loop is the device's."""
    import os

    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink.dialects.v20 import common as mavlink2

    if session.acc_unit not in ("g", "m/s^2") or session.gyro_unit != "rad/s":
        raise ImucalError("HIGHRES_IMU is made from g or m/s^2 and rad/s", source="--format")
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    acc = session.acc * (STANDARD_GRAVITY if session.acc_unit == "g" else 1.0)
    rows = np.column_stack([np.round(session.t_acc * 1e6), acc, session.gyro]).tolist()
    updated = 0b111111 | 1 << 12  # the accelerometer, the gyroscope and the temperature
    return [mav.highres_imu_encode(int(r[0]), *r[1:7], 0, 0, 0, 0, 0, 0, 25.0, updated)
            .pack(mav) for r in rows]


def frames_of(session: Session, fmt: str) -> tuple[list[bytes], list[bytes]]:
    """What a device sends first (a header line) and one frame per sample, as bytes."""
    if fmt == "mavlink":
        return [], mavlink_frames(session)
    header, lines = session_lines(session, fmt)
    return ([] if header is None else [(header + "\n").encode()],
            [(ln + "\n").encode() for ln in lines])


def paced(t: np.ndarray, frames: list[bytes], speed: float | None,
          send: Callable[[list[bytes]], None]) -> None:
    """Call ``send`` with the frames due every tick: sample i at ``t[i] / speed`` seconds from
    the first (all at once when ``speed`` is None)."""
    if speed is None:
        send(frames)
        return
    start = time.monotonic()
    due_at = (t - t[0]) / speed
    i = 0
    while i < len(frames):
        j = int(np.searchsorted(due_at, time.monotonic() - start, side="right"))
        if j > i:
            send(frames[i:j])
            i = j
        time.sleep(TICK_S)


def stream_session(session: Session, target: str, speed: float | None, fmt: str = "lines",
                   on_ready: Callable[[str], None] | None = None) -> None:
    """Send ``session`` to ``target``: ``-``, ``tcp://HOST:PORT`` or ``udp://HOST:PORT``, as
    lines (``lines``, ``motioncal``) or MAVLink frames (``mavlink``)."""
    head, frames = frames_of(session, fmt)
    t = session.t_acc
    if target == "-":
        out = sys.stdout.buffer

        def send(chunk: list[bytes]) -> None:
            out.write(b"".join(chunk))
            out.flush()

        send(head)
        paced(t, frames, speed, send)
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
                def send_tcp(chunk: list[bytes]) -> None:
                    conn.sendall(b"".join(chunk))

                send_tcp(head)
                paced(t, frames, speed, send_tcp)
        return
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        address = (host or "127.0.0.1", int(port))

        def send_udp(chunk: list[bytes]) -> None:
            packet: list[bytes] = []
            size = 0
            for frame in chunk:  # whole frames per datagram (a loop over the tick's frames)
                if packet and size + len(frame) > DATAGRAM:
                    sock.sendto(b"".join(packet), address)
                    packet, size = [], 0
                packet.append(frame)
                size += len(frame)
            if packet:
                sock.sendto(b"".join(packet), address)

        send_udp(head)
        paced(t, frames, speed, send_udp)
