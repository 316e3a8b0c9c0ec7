"""Choosing the streams to calibrate from a recording of many (method.md §0): the accelerometer
and gyroscope a user names with a selector, or else the first IMU, and the choice said.

A selector names a stream the way its source does: a ROS topic (``/imu/data_raw``), a ULog topic
and instance (``sensor_accel:1``), a DataFlash message (``IMU2``), an HDF5 path. It is matched
against the streams of the kind asked for: exactly, then ignoring case, then as the IMU the stream
belongs to (``--gyro IMU2`` finds the gyroscope of ``IMU2``), then as a 0-based position among
the streams of that kind (``--acc 1``: the second accelerometer).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from imucal.errors import ImucalError
from imucal.io.parts import Part
from imucal.streams import KIND_LABELS, Stream, StreamSet

# The unit a stream states, as the table loaders name it (their unit hints).
_HINTS = {"acc": {"g": "g", "m/s^2": "m/s^2", "counts": "counts"},
          "gyro": {"rad/s": "rad/s", "deg/s": "deg/s", "counts": "counts"}}
_OPTION = {"acc": "--acc", "gyro": "--gyro", "mag": "--mag", "temp": "--temp"}


@dataclass(frozen=True)
class Choice:
    """The streams taken for calibration, the others the recording holds, and what was said;
    ``sha256`` the file's, as its reader hashed the bytes it read ("" where it did not)."""

    acc: Stream
    gyro: Stream | None
    others: tuple[Stream, ...]
    said: tuple[str, ...]
    sha256: str = ""


def keep_for(selectors: dict[str, str | None]) -> Callable[[str], bool] | None:
    """What a reader may skip undecoded: with an accelerometer and a gyroscope both named, only
    the streams those names can match (a large log costs what the chosen topics cost); None
    (read every stream) when a default must be chosen among them all."""
    if selectors.get("acc") is None or selectors.get("gyro") is None:
        return None
    names = {s.lower() for s in selectors.values() if s is not None}
    if any(n.isdigit() for n in names):
        return None  # a position among the streams: every one must be seen

    def keep(instance: str) -> bool:
        return instance.lower() in names or instance.lower().split(":")[0] in names

    return keep


def find(streams: StreamSet, kind: str, selector: str) -> Stream:
    """The stream of ``kind`` that ``selector`` names; one line listing the candidates if none."""
    mine = streams.of_kind(kind)
    for match in (lambda s: s.instance == selector,
                  lambda s: s.instance.lower() == selector.lower(),
                  lambda s: (s.imu or "").lower() == selector.lower()):
        found = [s for s in mine if match(s)]
        if found:
            return found[0]
    if selector.isdigit() and int(selector) < len(mine):
        return mine[int(selector)]
    have = ", ".join(s.instance for s in mine) or "none"
    raise ImucalError(f"no {KIND_LABELS[kind]} stream {selector!r}; the file has: {have} "
                      "(imucal inspect lists every stream)", source=streams.source,
                      field=_OPTION[kind])


def choose(streams: StreamSet, selectors: dict[str, str | None], acc_only: bool) -> Choice:
    """The accelerometer and gyroscope to calibrate: those named, else the first IMU's (the
    first accelerometer, and the gyroscope of the same IMU, else the first gyroscope)."""
    said: list[str] = []
    accs = streams.of_kind("acc")
    if not accs:
        have = ", ".join(s.name for s in streams.streams) or "no sensor streams"
        raise ImucalError(f"no accelerometer stream to calibrate ({have})",
                          source=streams.source, field="streams")
    if selectors.get("acc") is not None:
        acc = find(streams, "acc", selectors["acc"])
    else:
        acc = accs[0]
        if len(accs) > 1:
            said.append(f"accelerometer {acc.instance} chosen, the first of {len(accs)} "
                        f"({', '.join(s.instance for s in accs)}); --acc names another")
    gyro = None
    if not acc_only:
        gyros = streams.of_kind("gyro")
        if selectors.get("gyro") is not None:
            gyro = find(streams, "gyro", selectors["gyro"])
        elif gyros:
            same = [s for s in gyros if acc.imu is not None and s.imu == acc.imu]
            gyro = (same or gyros)[0]
            if len(gyros) > 1:
                said.append(f"gyroscope {gyro.instance} chosen"
                            f"{', of the same IMU' if same else ''} from {len(gyros)} "
                            f"({', '.join(s.instance for s in gyros)}); --gyro names another")
        else:
            raise ImucalError("found an accelerometer and no gyroscope stream; name one with "
                              "--gyro, or --acc-only to calibrate the accelerometer alone",
                              source=streams.source, field="streams")
    for kind in ("mag", "temp"):
        if selectors.get(kind) is not None:
            find(streams, kind, selectors[kind])  # named: it must exist
    chosen = [acc] + ([gyro] if gyro is not None else [])
    others = tuple(s for s in streams.streams if all(s is not c for c in chosen))
    return Choice(acc, gyro, others, tuple(said), streams.sha256)


def parts_of(choice: Choice) -> dict[str, Part]:
    """The chosen streams as the loader's parts: seconds already, the stated unit as a hint."""
    parts = {}
    for sensor, stream in (("acc", choice.acc), ("gyro", choice.gyro)):
        if stream is None:
            continue
        parts[sensor] = Part(
            sensor=sensor, source=f"{stream.origin}", values=stream.values, time=stream.t,
            time_label=f"{stream.instance}'s {stream.time_source or 'timestamps'}",
            time_unit="s", time_unit_from="as the log states",
            unit_hint=_HINTS[sensor].get(stream.unit) if stream.unit else None)
    return parts


def describe(stream: Stream) -> str:
    """One line for calib.json and the report: which stream, from where, in which frame."""
    frame = f", frame {stream.frame}" if stream.frame else ""
    unit = f", {stream.unit}" if stream.unit else ""
    return f"{stream.name} ({stream.origin}{unit}{frame})"
