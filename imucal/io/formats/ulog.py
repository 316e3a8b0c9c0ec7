"""PX4 ULog (``.ulg``): the IMUs, magnetometers and their thermometers as streams, read with
pyulog's definitions and a compiled walk over the data (:mod:`.ulog_scan`).

What PX4 logs, and what it means (PX4-Autopilot ``msg/*.msg`` and ``src/lib/drivers``):

- ``sensor_accel`` (m/s^2) and ``sensor_gyro`` (rad/s), one multi-instance per chip: the
  driver's output with the driver's fixed chip-to-board rotation applied
  (``PX4Accelerometer::update`` calls ``rotate_3f(_rotation, ...)`` and scales), *before* any
  calibration (offsets, scales, thermal correction) and before the board-to-vehicle rotation
  ``SENS_BOARD_ROT`` (``calibration::Accelerometer::Correct`` applies those downstream). The
  message definition says "FRD board frame". This is the raw signal a calibration wants. (Older
  PX4, whose sensor_accel also carries ``x_raw`` or ``integral_dt``, applied its calibration
  in the driver: a stream of that layout says so in a note.)
  ``temperature`` (deg C) is the chip's; ``device_id`` names the chip (bus type, bus, address,
  device type).
- ``sensor_mag`` (gauss), likewise in the board frame (an external compass: its own mount,
  CAL_MAGn_ROT not applied), uncalibrated.
- ``sensor_combined``: the *selected* IMU, already calibrated by PX4 (offsets, scales, thermal
  correction) and rotated into the vehicle's FRD body frame (``SENS_BOARD_ROT``), averaged over
  its integration period. Its gyroscope time is ``timestamp``; the accelerometer's is
  ``timestamp + accelerometer_timestamp_relative`` (0x7fffffff marks an invalid sample).

Clock: ``timestamp_sample`` (when the chip sampled) where the topic has it, else
``timestamp`` (when PX4 published); both microseconds since boot, here in seconds.

The walk: one compiled pass finds every message of the file; the wanted topics' format
definitions are parsed by pyulog (``ULog.MessageFormat``), their subscriptions read, and their
data messages' payloads copied out and viewed as records of the topic's layout, so the cost is
the file's bytes, not a Python step per message. A file the walk finds irregular (an unknown
message type, data appended after a crash) is read by pyulog itself, which recovers at sync
markers, message by message (``fast=False`` reads every file that way).
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import struct
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from imucal.errors import ImucalError, plural
from imucal.io.formats.clock import in_time_order
from imucal.streams import Stream, StreamSet

SENSOR_TOPICS = ("sensor_accel", "sensor_gyro", "sensor_mag", "sensor_combined")
FORMAT_NAME = "PX4 ULog"
MAGIC = b"ULog\x01\x12\x35"
BOARD_FRAME = "FRD (PX4 board frame: driver rotation only, before SENS_BOARD_ROT)"
BODY_FRAME = "FRD (PX4 body frame: SENS_BOARD_ROT applied)"
_INVALID_RELATIVE = 0x7FFFFFFF  # sensor_combined.RELATIVE_TIMESTAMP_INVALID
# ULog field types (ULog File Format specification) as little-endian numpy types; bool and char
# as int8, like pyulog, so the records compare field for field.
_TYPES = {"int8_t": "<i1", "uint8_t": "<u1", "int16_t": "<i2", "uint16_t": "<u2",
          "int32_t": "<i4", "uint32_t": "<u4", "int64_t": "<i8", "uint64_t": "<u8",
          "float": "<f4", "double": "<f8", "bool": "<i1", "char": "<i1"}
# The fields each topic's streams are made of.
_XYZ = ("x", "y", "z")
_NEEDED = {"sensor_accel": _XYZ, "sensor_gyro": _XYZ, "sensor_mag": _XYZ,
           "sensor_combined": ("gyro_rad[0]", "gyro_rad[1]", "gyro_rad[2]",
                               "accelerometer_timestamp_relative", "accelerometer_m_s2[0]",
                               "accelerometer_m_s2[1]", "accelerometer_m_s2[2]")}
_BUS_TYPES = {0: "unknown bus", 1: "I2C", 2: "SPI", 3: "UAVCAN", 4: "simulation", 5: "serial",
              6: "MAVLink"}


def read_streams(path: Path, source: str, keep: Callable[[str], bool] | None,
                 key: str = "ulog", *, fast: bool = True) -> StreamSet:
    """Every ``sensor_accel``, ``sensor_gyro``, ``sensor_mag`` instance and ``sensor_combined``
    of a ULog as streams (with the chips' temperatures); only instances ``keep`` accepts
    (``sensor_accel:1``, ``sensor_combined``) are decoded. ``fast=False`` reads with pyulog
    alone (the reference the compiled walk is tested against)."""
    buf = _map(path, source)
    digest = hashlib.sha256(buf).hexdigest()
    if bytes(buf[:7]) != MAGIC:
        raise ImucalError("not a ULog: the file does not start with ULog's magic bytes",
                          source=source)
    try:
        topics, notes = _walk(buf, keep, source) if fast else _read_with_pyulog(path, source,
                                                                                 keep)
    except _Irregular as irregular:
        topics, notes = _read_with_pyulog(path, source, keep)
        notes.insert(0, f"{irregular}: read by pyulog's parser, which skips what it cannot read")
    streams = _streams(topics, notes)
    if not streams and keep is None:
        cut = next((n.split(";")[0] for n in notes if n.startswith("truncated")), None)
        raise ImucalError(f"{cut}, before any sensor sample" if cut else
                          "the log subscribes sensor topics but holds no sensor sample",
                          source=source)
    return StreamSet(source=source, format=FORMAT_NAME, streams=tuple(streams), sha256=digest,
                     notes=tuple(notes))


# --- the file -----------------------------------------------------------------------------


def _map(path: Path, source: str) -> np.ndarray:
    try:
        size = path.stat().st_size
        if size < 16:
            raise ImucalError(f"a ULog starts with a 16-byte header; the file has {size} bytes",
                              source=source)
        # a plain view of the mapping: slicing a np.memmap makes memmap objects, slowly
        return np.memmap(path, dtype=np.uint8, mode="r").view(np.ndarray)
    except OSError as err:
        raise ImucalError(f"cannot read the file: {err.strerror or err}", source=source) from None


def _printed(printed: io.StringIO, notes: list[str]) -> None:
    """pyulog prints its warnings; they become notes, not lines on the user's terminal."""
    lines = list(dict.fromkeys(s.strip() for s in printed.getvalue().splitlines() if s.strip()))
    notes.extend(f"pyulog: {s}" for s in lines[:3])


@dataclass
class _Topic:
    name: str
    multi_id: int
    fields: dict[str, np.ndarray]

    @property
    def instance(self) -> str:
        return "sensor_combined" if self.name == "sensor_combined" else \
            f"{self.name}:{self.multi_id}"


def _flat_dtype(name: str, formats: dict) -> np.dtype:
    """The packed record of topic ``name``: nested types flattened to ``a.b[1].c`` names and
    trailing padding dropped, as PX4 writes it and pyulog reads it."""
    fields: list[tuple[str, str]] = []

    def walk(type_name: str, prefix: str) -> None:
        for type_str, size, field in formats[type_name].fields:
            names = [f"{prefix}{field}[{i}]" for i in range(size)] if size else [prefix + field]
            for n in names:
                if type_str in _TYPES:
                    fields.append((n, _TYPES[type_str]))
                else:
                    walk(type_str, n + ".")

    walk(name, "")
    while fields and fields[-1][0].startswith("_padding"):
        fields.pop()
    return np.dtype(fields)


class _Irregular(Exception):
    """The file needs pyulog's recovering parser (a corrupt stretch, data appended after a
    crash, a message id subscribed twice); the message says what was met."""


def _walk(buf: np.ndarray, keep: Callable[[str], bool] | None, source: str):
    """The wanted topics' records by the compiled walk, and notes."""
    from imucal.io.formats import ulog_scan

    offsets, stop, status = ulog_scan.message_offsets(buf, 16)
    if status == ulog_scan.IRREGULAR:
        raise _Irregular(f"a message header no ULog writer makes at byte {stop} (type "
                         f"{int(buf[stop + 2])}, size {_size(buf, stop)})")
    notes: list[str] = []
    cut = (f"truncated: the file ends inside a message (byte {stop}, "
           f"{plural(len(buf) - stop, 'byte')} of it present)"
           if status == ulog_scan.TRUNCATED else None)
    if cut:
        notes.append(cut + "; read up to there")
    if not len(offsets):
        raise ImucalError(cut or "the file holds a ULog header and no message", source=source)
    kinds = buf[offsets + 2]
    if len(offsets) and kinds[0] == ord("B"):
        # Flag bits (ULog spec): incompat_flags[0] bit 0 = data appended after the end (pyulog
        # seeks there); any other incompatible bit = a layout no reader knows (pyulog refuses).
        incompat = buf[offsets[0] + 3 + 8:offsets[0] + 3 + 16]
        if int(incompat[0]) & 0xFE or incompat[1:].any():
            raise ImucalError("the ULog sets an incompatible flag this reader does not know",
                              source=source)
        if int(incompat[0]) & 1:
            raise _Irregular("data appended after the log's end (the incompatible flag set "
                             "after a crash)")
    drops = offsets[kinds == ord("O")]
    if len(drops):  # dropout messages: the logger lost data for uint16 duration ms each
        lost = int((buf[drops + 3].astype(np.int64) | buf[drops + 4].astype(np.int64) << 8).sum())
        notes.append(f"the logger dropped data {plural(len(drops), 'time')} ({lost} ms in all): "
                     "every topic has gaps there")
    formats = _Formats()
    for o in offsets[kinds == ord("F")].tolist():
        text = bytes(buf[o + 3:o + 3 + _size(buf, o)])
        formats.raw[text.split(b":", 1)[0].decode("ascii", "replace")] = text
    subs = offsets[kinds == ord("A")]
    subscribed: dict[int, tuple[str, int]] = {}
    for o in subs.tolist():
        payload = bytes(buf[o + 3:o + 3 + _size(buf, o)])
        msg_id = int.from_bytes(payload[1:3], "little")
        if msg_id in subscribed:  # reused after a removal: pyulog's rule (the last wins)
            raise _Irregular(f"message id {msg_id} subscribed twice")
        subscribed[msg_id] = (payload[3:].split(b"\0")[0].decode("ascii", "replace"),
                              payload[0])
    data = offsets[kinds == ord("D")]
    ids = buf[data + 3].astype(np.int64) | (buf[data + 4].astype(np.int64) << 8)
    sizes = buf[data].astype(np.int64) | (buf[data + 1].astype(np.int64) << 8)
    topics: list[_Topic] = []
    names = sorted({n for n, _ in subscribed.values()})
    if cut and not any(n in SENSOR_TOPICS for n in names):
        raise ImucalError(f"{cut}, before any sensor topic is logged", source=source)
    _no_sensors(names, source)
    for msg_id, (name, multi_id) in sorted(subscribed.items(), key=lambda s: (s[1], s[0])):
        topic = _Topic(name, multi_id, {})
        if name not in SENSOR_TOPICS or (keep is not None and not keep(topic.instance)):
            continue
        if name not in formats:
            notes.append(f"{topic.instance}: no format definition; not read")
            continue
        try:
            dtype = _flat_dtype(name, formats)
        except (KeyError, ValueError, IndexError, TypeError):
            notes.append(f"{topic.instance}: its format definition is incomplete or corrupt; "
                         "not read")
            continue
        mine = ids == msg_id
        # pyulog keeps a record whose payload is exactly the format's size (after its msg_id)
        # and counts any other as corrupt: the same rule, so both readings agree.
        good = mine & (sizes - 2 == dtype.itemsize)
        bad = int(np.count_nonzero(mine)) - int(np.count_nonzero(good))
        if bad:
            notes.append(f"{topic.instance}: {plural(bad, 'message')} of the wrong size "
                         "skipped (corrupt)")
        if not good.any():
            notes.append(f"{topic.instance}: subscribed, but no sample logged")
            continue
        records = ulog_scan.gather(buf, data[good] + 5, dtype.itemsize).view(dtype).ravel()
        topic.fields = {f: records[f] for f in dtype.names}
        topics.append(topic)
    return topics, notes


class _Formats(dict):
    """The format definitions by name, each parsed by pyulog's ``ULog.MessageFormat`` when
    first asked for (a log defines ~80; a sensor read needs a handful)."""

    def __init__(self) -> None:
        super().__init__()
        self.raw: dict[str, bytes] = {}

    def __contains__(self, name: object) -> bool:
        return name in self.raw

    def __missing__(self, name: str):
        from pyulog import ULog

        self[name] = fmt = ULog.MessageFormat(self.raw[name], None)
        return fmt


def _size(buf: np.ndarray, o: int) -> int:
    return int(buf[o]) | int(buf[o + 1]) << 8


def _read_with_pyulog(path: Path, source: str, keep: Callable[[str], bool] | None):
    from pyulog import ULog
    from pyulog.exceptions import ULogException

    printed = io.StringIO()
    try:
        with contextlib.redirect_stdout(printed):
            log = ULog(str(path), message_name_filter_list=list(SENSOR_TOPICS))
    except (ULogException, UnicodeDecodeError, ValueError, struct.error) as err:
        raise ImucalError(f"not a readable ULog: {_one_line(err)}", source=source) from None
    notes: list[str] = []
    _printed(printed, notes)
    if log.dropouts:
        notes.append(f"the logger dropped data {plural(len(log.dropouts), 'time')} "
                     f"({sum(d.duration for d in log.dropouts)} ms in all): every topic has gaps "
                     "there")
    if log.file_corruption:
        notes.append("corrupt stretches: read by pyulog, which skips to the next sync marker")
    topics = [_Topic(d.name, d.multi_id, dict(d.data)) for d in log.data_list]
    if not topics:  # say what the log holds instead: read it all (a refusal, so no hurry)
        with contextlib.redirect_stdout(io.StringIO()):
            names = sorted({d.name for d in ULog(str(path)).data_list})
        _no_sensors(names, source)
    return [t for t in topics if keep is None or keep(t.instance)], notes


def _no_sensors(names: list[str], source: str) -> None:
    if any(n in SENSOR_TOPICS for n in names):
        return
    most = 8
    listed = ", ".join(names[:most]) + (f" and {len(names) - most} more" if len(names) > most
                                        else "")
    raise ImucalError(f"no sensor topic ({', '.join(SENSOR_TOPICS)}) in the log; it has "
                      f"{plural(len(names), 'topic')}{': ' + listed if listed else ''}",
                      source=source)


# --- streams ------------------------------------------------------------------------------


def _clock(topic: _Topic, t_us: np.ndarray, notes: list[str]):
    """Seconds, and the order that sorts them with repeated stamps dropped (first kept)."""
    t_sorted, order = in_time_order(t_us, topic.instance, notes, unit="sample")
    return t_sorted.astype(np.float64) / 1e6, order  # division: correctly rounded


def describe_device(device_id: int) -> str:
    """A PX4 device_id as PX4 packs it (``device::Device::DeviceStructure``: bus type in bits
    0-2, bus 3-7, address 8-15, device type 16-23): ``0x25000a (SPI bus 1, address 0x00,
    devtype 0x25)``."""
    bus_type, bus = device_id & 0x7, (device_id >> 3) & 0x1F
    address, devtype = (device_id >> 8) & 0xFF, (device_id >> 16) & 0xFF
    return (f"{device_id:#x} ({_BUS_TYPES.get(bus_type, 'bus type ' + str(bus_type))} bus "
            f"{bus}, address {address:#04x}, devtype {devtype:#04x})")


def _device(topic: _Topic, notes: list[str]) -> str | None:
    ids = topic.fields.get("device_id")
    if ids is None or not len(ids):
        return None
    unique = np.unique(ids)
    if len(unique) > 1:
        notes.append(f"{topic.instance}: device_id changes within the log "
                     f"({', '.join(hex(int(u)) for u in unique)}); the first is named")
    return describe_device(int(ids[0]))


def _triad(topic: _Topic, names: tuple[str, str, str]) -> np.ndarray:
    return np.column_stack([topic.fields[n].astype(np.float64) for n in names])


def _pairs(topics: list[_Topic], notes: list[str]) -> dict[str, str]:
    """The IMU each accelerometer and gyroscope instance belongs to. PX4's IMU drivers publish
    an accelerometer and a gyroscope with the same device_id (one chip): those pair; an
    instance without such a partner pairs with the other kind's instance of the same index
    when that one is unpaired too (said in a note), else stands alone."""
    acc = {t.multi_id: t for t in topics if t.name == "sensor_accel"}
    gyro = {t.multi_id: t for t in topics if t.name == "sensor_gyro"}

    def dev(t: _Topic) -> int | None:
        ids = t.fields.get("device_id")
        return int(ids[0]) if ids is not None and len(ids) else None

    imu: dict[str, str] = {}
    free_gyro = dict(gyro)
    for a in acc.values():
        same = [j for j, g in free_gyro.items() if dev(g) is not None and dev(g) == dev(a)]
        if same:
            g = free_gyro.pop(same[0])
            imu[a.instance] = imu[g.instance] = f"{a.instance}+{g.instance}"
    for i, a in sorted(acc.items()):
        if a.instance in imu:
            continue
        if i in free_gyro:
            g = free_gyro.pop(i)
            imu[a.instance] = imu[g.instance] = f"{a.instance}+{g.instance}"
            notes.append(f"{a.instance} and {g.instance} paired by instance number: no "
                         "gyroscope has the accelerometer's device_id")
        else:
            imu[a.instance] = a.instance
    for g in free_gyro.values():
        imu[g.instance] = g.instance
    return imu


def _streams(topics: list[_Topic], notes: list[str]) -> list[Stream]:
    imu = _pairs(topics, notes)
    streams: list[Stream] = []
    temps: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for topic in topics:
        f = topic.fields
        if not len(f.get("timestamp", ())):
            continue
        missing = [n for n in _NEEDED[topic.name] if n not in f]
        if missing:
            notes.append(f"{topic.instance}: no field {', '.join(missing)} (a PX4 layout this "
                         "reader does not know); not read")
            continue
        local: list[str] = []
        if topic.name == "sensor_combined":
            streams.extend(_combined(topic))
            continue
        kind, unit = {"sensor_accel": ("acc", "m/s^2"), "sensor_gyro": ("gyro", "rad/s"),
                      "sensor_mag": ("mag", "gauss")}[topic.name]
        stamp = "timestamp_sample" if "timestamp_sample" in f else "timestamp"
        t, order = _clock(topic, f[stamp], local)
        device = _device(topic, local)
        origin = f"ULog topic {topic.name}, multi-instance {topic.multi_id}, fields x, y, z"
        time_source = f"{stamp} (µs since boot)"
        values = _triad(topic, _XYZ)[order]
        if topic.name != "sensor_mag" and ("x_raw" in f or "integral_dt" in f):
            local.append(f"{topic.instance}: an older PX4 layout (x_raw/integral_dt), whose "
                         "driver applied PX4's calibration (CAL_ACCn/CAL_GYROn) already")
        streams.append(Stream(kind, topic.instance, t, values, unit, origin, BOARD_FRAME,
                              time_source, device, imu.get(topic.instance),
                              notes=tuple(local)))
        temp = f.get("temperature")
        if temp is None:
            continue
        temp = temp.astype(np.float64)[order]
        if not np.isfinite(temp).any():
            continue  # PX4 fills NaN where a chip has no thermometer (most compasses)
        # An accelerometer and gyroscope of one chip report the one thermometer: the gyro's
        # copy is not repeated when it equals its partner's sample for sample.
        partner = imu.get(topic.instance)
        if partner in temps and np.array_equal(temps[partner][0], t) and \
                np.array_equal(temps[partner][1], temp, equal_nan=True):
            notes.append(f"{topic.instance}: temperature identical to its IMU partner's; "
                         "one temp stream kept")
            continue
        if partner is not None:
            temps.setdefault(partner, (t, temp))
        streams.append(Stream("temp", topic.instance, t, temp[:, None], "degC",
                              f"ULog topic {topic.name}, multi-instance {topic.multi_id}, "
                              "field temperature", None, time_source, device,
                              imu.get(topic.instance)))
    return streams


def _combined(topic: _Topic) -> list[Stream]:
    f = topic.fields
    out: list[Stream] = []
    origin = "ULog topic sensor_combined (PX4's selected IMU, calibrated by PX4)"
    calibrated = ("PX4 has already applied its own calibration (offsets, scales, thermal "
                  "correction) and the board rotation")
    t_gyro = f["timestamp"].astype(np.int64)
    gyro_local = [calibrated]
    t, order = _clock(topic, t_gyro, gyro_local)
    out.append(Stream("gyro", topic.instance, t,
                      _triad(topic, ("gyro_rad[0]", "gyro_rad[1]", "gyro_rad[2]"))[order],
                      "rad/s", origin + ", field gyro_rad", BODY_FRAME,
                      "timestamp (µs since boot; the gyroscope's sample time)", None,
                      "sensor_combined", tuple(gyro_local)))
    rel = f["accelerometer_timestamp_relative"].astype(np.int64)
    valid = rel != _INVALID_RELATIVE
    acc_local = [calibrated]
    if not valid.all():
        acc_local.append(f"{plural(int((~valid).sum()), 'sample')} marked invalid "
                         "(accelerometer_timestamp_relative = 0x7fffffff) dropped")
    t, order = _clock(topic, (t_gyro + rel)[valid], acc_local)
    acc = _triad(topic, ("accelerometer_m_s2[0]", "accelerometer_m_s2[1]",
                         "accelerometer_m_s2[2]"))[valid][order]
    out.append(Stream("acc", topic.instance, t, acc, "m/s^2",
                      origin + ", field accelerometer_m_s2", BODY_FRAME,
                      "timestamp + accelerometer_timestamp_relative (µs since boot)", None,
                      "sensor_combined", tuple(acc_local)))
    return out


def _one_line(err: BaseException) -> str:
    text = " ".join(str(err).split()) or type(err).__name__
    return text if len(text) <= 200 else text[:197] + "..."
