"""MAVLink as a capture source: ``mavlink:udp:HOST:PORT`` (listen, as a ground station does) or
``mavlink:/dev/ttyACM0?baud=N``, read with pymavlink (imported only here).

The first IMU message that arrives chooses the stream (its type and sender; the others are
left): ``HIGHRES_IMU`` (m/s^2, rad/s, gauss, degC, µs), ``SCALED_IMU``/``2``/``3`` (mg, mrad/s
converted to rad/s, mgauss, cdegC converted to degC, ms since boot) or ``RAW_IMU`` (counts,
µs). Each message becomes a line of the session file under names that say the units, so the
table loader reads the file as the capture read the stream. Bytes that form no MAVLink message
are counted as garbled.
"""

from __future__ import annotations

from urllib.parse import parse_qs, urlsplit

from imucal.capture.byte_source import Source
from imucal.errors import ImucalError

_AXES = ("xacc", "yacc", "zacc", "xgyro", "ygyro", "zgyro", "xmag", "ymag", "zmag")
# type -> (time field, the session file's names, per-column factors after time, temperature
# field and its factor to degC)
_SCALED = (("time_boot_ms", "t (ms)"),
           ["ax (mg)", "ay (mg)", "az (mg)", "gx (rad/s)", "gy (rad/s)", "gz (rad/s)",
            "mx (mG)", "my (mG)", "mz (mG)", "temp (degC)"],
           (1, 1, 1, 1e-3, 1e-3, 1e-3, 1, 1, 1, 1e-2))
MESSAGES = {
    "HIGHRES_IMU": (("time_usec", "t (us)"),
                    ["ax (m/s^2)", "ay (m/s^2)", "az (m/s^2)", "gx (rad/s)", "gy (rad/s)",
                     "gz (rad/s)", "mx (gauss)", "my (gauss)", "mz (gauss)", "temp (degC)"],
                    (1,) * 10),
    "SCALED_IMU": _SCALED, "SCALED_IMU2": _SCALED, "SCALED_IMU3": _SCALED,
    "RAW_IMU": (("time_usec", "t (us)"),
                ["ax (counts)", "ay (counts)", "az (counts)", "gx (counts)", "gy (counts)",
                 "gz (counts)", "mx (counts)", "my (counts)", "mz (counts)", "temp (degC)"],
                (1,) * 9 + (1e-2,)),
}


class MavlinkSource(Source):
    @property
    def hint(self) -> str:
        seen = ", ".join(sorted(self.seen)) or "none"
        return ("the port or the baud rate, and that the device sends RAW_IMU, SCALED_IMU or "
                f"HIGHRES_IMU (message types seen: {seen})")

    def __init__(self, spec: str):
        import os

        os.environ.setdefault("MAVLINK20", "1")  # parse MAVLink 2 and 1 alike
        from pymavlink import mavutil

        self.describe = spec
        device = spec[len("mavlink:"):]
        baud = 115200
        if not device.startswith(("udp:", "udpin:", "tcp:")):
            parts = urlsplit(device)
            device = parts.path
            try:
                baud = int(parse_qs(parts.query).get("baud", [baud])[0])
            except ValueError as e:
                raise ImucalError("baud must be a whole number", source=spec,
                                  field="baud") from e
        try:
            self.conn = mavutil.mavlink_connection(device, baud=baud, robust_parsing=True,
                                                   source_system=255)
        except Exception as e:  # pymavlink raises what its transport raises
            raise ImucalError(f"cannot open: {e}", source=spec) from e
        self.chosen: tuple[str, int, int] | None = None
        self.garbled = 0
        self.seen: set[str] = set()

    def read(self, timeout: float) -> bytes | None:
        lines: list[str] = []
        try:
            msg = self.conn.recv_match(blocking=True, timeout=max(timeout, 0.001))
            while msg is not None:
                self._take(msg, lines)
                msg = self.conn.recv_match(blocking=False)
        except (OSError, ValueError):  # a pulled cable, a closed port
            return None if not lines else ("\n".join(lines) + "\n").encode()
        return ("\n".join(lines) + "\n").encode() if lines else b""

    def _take(self, msg, lines: list[str]) -> None:
        kind = msg.get_type()
        if kind == "BAD_DATA":
            self.garbled += 1
            return
        self.seen.add(kind)
        if kind not in MESSAGES:
            return
        sender = (kind, msg.get_srcSystem(), msg.get_srcComponent())
        (time_field, time_name), names, factors = MESSAGES[kind]
        if self.chosen is None:
            self.chosen = sender
            lines.append(",".join([time_name, *names]))
        if sender != self.chosen:
            return
        values = [getattr(msg, f) * k for f, k in zip((*_AXES, "temperature"), factors)]
        lines.append(",".join(repr(v) for v in [getattr(msg, time_field), *values]))

    def close(self) -> None:
        self.conn.close()
