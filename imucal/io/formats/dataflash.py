"""ArduPilot DataFlash logs (``.bin``) and MAVLink telemetry logs (``.tlog``): the IMUs,
compasses and thermometers as streams, read with pymavlink.

DataFlash (ArduPilot ``libraries/AP_InertialSensor/AP_InertialSensor_Logging.cpp``,
``AP_Compass``), every vector in ArduPilot's body frame, FRD (the board rotation
``AHRS_ORIENTATION`` applied):

- ``IMU``, ``IMU2``, ``IMU3`` (older logs) or ``IMU`` with an instance field ``I`` (newer):
  ``AccX..Z`` m/s^2, ``GyrX..Z`` rad/s, ``T`` deg C, at ``TimeUS``. What ArduPilot flies on:
  after its own calibration (INS_ACCOFFS/ACCSCAL, gyro offsets, temperature calibration where
  enabled) and its low-pass filters (INS_ACCEL_FILTER, INS_GYRO_FILTER), once per logging loop.
- ``ACC``/``GYR`` with ``I`` (newer) or ``ACC1..3``/``GYR1..3`` (older): every sample at the
  sensor's rate, after the calibration, at ``SampleUS`` (when the sensor sampled); written only
  when raw IMU logging is enabled.
- ``MAG``, ``MAG2``, ``MAG3`` (or ``MAG`` with ``I``): ``MagX..Z`` in milligauss, the field
  ArduPilot uses (its compass offsets, logged beside as ``OfsX..Z``, already subtracted), at
  ``TimeUS``.

MAVLink (common.xml), the message's own clock (``time_usec`` µs or ``time_boot_ms`` ms):

- ``SCALED_IMU``, ``SCALED_IMU2``, ``SCALED_IMU3``: accelerometer in mg, stated here in g
  (divided by 1000), gyroscope in mrad/s, stated in rad/s (divided by 1000), magnetometer in
  mgauss (kept, unit ``mG``), ``temperature`` in cdeg C, stated in deg C (divided by 100;
  0 means "no thermometer", MAVLink's rule).
- ``RAW_IMU``: "raw" values, unit ``counts`` as MAVLink defines them (ArduPilot in fact sends
  the scaled mg, mrad/s and mgauss values here too; the loader's unit guess decides).
- ``HIGHRES_IMU``: m/s^2, rad/s, gauss, deg C.

DataFlash: pymavlink's compiled indexer finds where every message lies; the wanted types are
then viewed as numpy records of their FMT layout at those offsets (equal, column for column, to
pymavlink's own message-by-message decoding, which ``fast=False`` uses). MAVLink: pymavlink
decodes the telemetry log message by message in Python (tlogs are telemetry rates); the values
are collected and made one array per message type.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from imucal.errors import ImucalError, plural
from imucal.io.formats.clock import in_time_order
from imucal.streams import Stream, StreamSet

FORMAT_NAMES = {"dataflash": "ArduPilot DataFlash log", "tlog": "MAVLink telemetry log"}
AP_FRAME = "FRD (ArduPilot body frame: AHRS_ORIENTATION applied)"
_CALIBRATED = "ArduPilot has already applied its own calibration"


# --- what is read ---------------------------------------------------------------------------


@dataclass(frozen=True)
class _Triad:
    kind: str
    columns: tuple[str, str, str]
    unit: str
    scale: float = 1.0  # divide by it: the stated unit from the message's


@dataclass(frozen=True)
class _Layout:
    """One message type's streams: the triads, the thermometer, the clock, and what to say."""

    triads: tuple[_Triad, ...]
    clock: tuple[str, ...]  # clock columns, the first present wins
    clock_units: float  # per second (divided by: a correctly rounded result)
    temp: tuple[str, float] | None = None  # (column, divide by)
    note: str = ""
    temp_zero_is_missing: bool = False


_IMU = _Layout((_Triad("acc", ("AccX", "AccY", "AccZ"), "m/s^2"),
                _Triad("gyro", ("GyrX", "GyrY", "GyrZ"), "rad/s")),
               ("TimeUS",), 1e6, ("T", 1.0),
               f"{_CALIBRATED} and its low-pass filters (INS_ACCEL_FILTER, INS_GYRO_FILTER); "
               "one sample per logging loop")
_ACC = _Layout((_Triad("acc", ("AccX", "AccY", "AccZ"), "m/s^2"),), ("SampleUS", "TimeUS"),
               1e6, None, f"every sensor sample; {_CALIBRATED}")
_GYR = _Layout((_Triad("gyro", ("GyrX", "GyrY", "GyrZ"), "rad/s"),), ("SampleUS", "TimeUS"),
               1e6, None, f"every sensor sample; {_CALIBRATED}")
_MAG = _Layout((_Triad("mag", ("MagX", "MagY", "MagZ"), "mG"),), ("TimeUS",), 1e6, None,
               "ArduPilot's compass calibration already applied (offsets, logged beside as "
               "OfsX..Z; soft iron; motor compensation MOfsX..Z)")
DATAFLASH = {"IMU": _IMU, "IMU2": _IMU, "IMU3": _IMU,
             "ACC": _ACC, "ACC1": _ACC, "ACC2": _ACC, "ACC3": _ACC,
             "GYR": _GYR, "GYR1": _GYR, "GYR2": _GYR, "GYR3": _GYR,
             "MAG": _MAG, "MAG2": _MAG, "MAG3": _MAG}

_SCALED = _Layout((_Triad("acc", ("xacc", "yacc", "zacc"), "g", 1000.0),
                   _Triad("gyro", ("xgyro", "ygyro", "zgyro"), "rad/s", 1000.0),
                   _Triad("mag", ("xmag", "ymag", "zmag"), "mG")),
                  ("time_boot_ms",), 1e3, ("temperature", 100.0),
                  "MAVLink's mg and mrad/s divided by 1000 (g, rad/s), cdegC by 100",
                  temp_zero_is_missing=True)
_RAW = _Layout((_Triad("acc", ("xacc", "yacc", "zacc"), "counts"),
                _Triad("gyro", ("xgyro", "ygyro", "zgyro"), "counts"),
                _Triad("mag", ("xmag", "ymag", "zmag"), "counts")),
               ("time_usec",), 1e6, ("temperature", 100.0),
               "MAVLink defines RAW_IMU as unscaled sensor values (ArduPilot sends mg, mrad/s "
               "and mgauss in it)", temp_zero_is_missing=True)
_HIGHRES = _Layout((_Triad("acc", ("xacc", "yacc", "zacc"), "m/s^2"),
                    _Triad("gyro", ("xgyro", "ygyro", "zgyro"), "rad/s"),
                    _Triad("mag", ("xmag", "ymag", "zmag"), "gauss")),
                   ("time_usec",), 1e6, ("temperature", 1.0))
TLOG = {"SCALED_IMU": _SCALED, "SCALED_IMU2": _SCALED, "SCALED_IMU3": _SCALED,
        "RAW_IMU": _RAW, "HIGHRES_IMU": _HIGHRES}


@dataclass
class _Rows:
    """One message type's (or instance's) numeric values as pymavlink decoded them: one row a
    message, ``columns`` naming the table's columns."""

    columns: dict[str, int]
    table: np.ndarray


def _table(rows: list, columns: dict[str, int], wanted: set[str]) -> _Rows:
    """The ``wanted`` columns of ``rows`` (lists of decoded values) as one float64 array: the
    one conversion of a message type's values (other columns may hold text)."""
    keep = sorted(c for c in wanted if c in columns)
    idx = [columns[c] for c in keep]
    if not rows:
        return _Rows({c: j for j, c in enumerate(keep)}, np.empty((0, len(keep))))
    table = np.array(rows, dtype=object)[:, idx].astype(np.float64)
    return _Rows({c: j for j, c in enumerate(keep)}, table)


def _needed(layout: _Layout) -> set[str]:
    cols = {c for tr in layout.triads for c in tr.columns} | set(layout.clock) | {"I"}
    return cols | ({layout.temp[0]} if layout.temp else set())


def read_streams(path: Path, source: str, keep: Callable[[str], bool] | None,
                 key: str, *, fast: bool = True) -> StreamSet:
    """Every IMU, compass and thermometer message of an ArduPilot DataFlash log (``key``
    "dataflash") or MAVLink telemetry log ("tlog") as streams; a message type ``keep`` rejects
    (``IMU2``, ``SCALED_IMU``; ``IMU[1]`` for an instance field) is not decoded.
    ``fast=False`` decodes DataFlash messages one by one with pymavlink (the reference)."""
    name = FORMAT_NAMES[key]
    try:
        data = path.read_bytes()
    except OSError as err:
        raise ImucalError(f"cannot read the file: {err.strerror or err}", source=source) from None
    digest = hashlib.sha256(data).hexdigest()
    printed = io.StringIO()
    try:
        with _silenced(printed):
            if key == "tlog":
                found, present, reader_notes = _read_tlog(path, keep)
                layouts = TLOG
            else:
                found, present, reader_notes = _read_dataflash(path, keep, fast)
                layouts = DATAFLASH
    except ImucalError:
        raise
    except Exception as err:  # pymavlink raises what its parser meets: one line, no traceback
        raise ImucalError(f"cannot read the {name}: {_one_line(err)}", source=source) from None
    lines = _lines(printed)
    bad = [s for s in lines if s.startswith("bad header")]
    notes = [f"pymavlink: {s}" for s in lines if s not in bad][:3]
    if bad:
        notes.append(f"corrupt stretches: pymavlink skipped {plural(len(bad), 'byte')} that "
                     "start no valid message")
    notes.extend(reader_notes)
    if not any(t.split("[")[0] in layouts for t in present):
        listed = ", ".join(sorted(present)[:8]) + (
            f" and {len(present) - 8} more" if len(present) > 8 else "")
        raise ImucalError(f"no IMU or compass message ({', '.join(layouts)}) in the {name}; "
                          f"it has {plural(len(present), 'message type')}"
                          f"{': ' + listed if listed else ''}", source=source)
    streams: list[Stream] = []
    for instance, rows in found.items():
        streams.extend(_streams(instance, layouts[instance.split("[")[0].split("@")[0]],
                                rows, key, notes))
    if not streams and keep is None:
        raise ImucalError(f"the {name}'s IMU and compass messages hold no usable sample",
                          source=source)
    return StreamSet(source=source, format=name, streams=tuple(streams), sha256=digest,
                     notes=tuple(notes))


def _lines(printed: io.StringIO) -> list[str]:
    return [s.strip() for s in printed.getvalue().splitlines() if s.strip()]


_FD_LOCK = threading.Lock()  # one redirection of the process's descriptors at a time


@contextlib.contextmanager
def _silenced(printed: io.StringIO):
    """pymavlink reports what it skips by printing, from Python and from its compiled DataFlash
    indexer (C, on file descriptor 1): both are caught here, for notes, instead of flooding the
    user's terminal (one line per bad byte). The descriptors are the process's: readers in
    several threads take turns (a lock), and where they cannot be duplicated (closed), only
    Python's printing is caught."""
    import os
    import sys
    import tempfile

    for stream in (sys.stdout, sys.stderr):  # what Python holds for the real descriptors
        if stream is not None:
            stream.flush()
    with _FD_LOCK, tempfile.TemporaryFile() as sink, \
            contextlib.redirect_stdout(printed), contextlib.redirect_stderr(printed):
        try:
            saved = [os.dup(1), os.dup(2)]
        except OSError:
            yield
            return
        os.dup2(sink.fileno(), 1)
        os.dup2(sink.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for fd in saved:
                os.close(fd)
            sink.seek(0)
            printed.write(sink.read().decode("utf-8", "replace"))


def _read_dataflash(path: Path, keep: Callable[[str], bool] | None, fast: bool = True):
    """pymavlink's DataFlash reader: its index of where each message type's messages lie
    (``DFReader_binary.offsets``, built by its compiled indexer), then the wanted types decoded
    from those offsets as numpy records of the type's ``FMT`` layout (``fast``), or message by
    message with ``recv_match`` (``fast=False``, the reference); one array per type, the
    format's multipliers applied per column as pymavlink applies them, split by the instance
    field ``I`` where the format has one."""
    from pymavlink import DFReader

    class Reader(DFReader.DFReader_binary):
        def __init__(self, *args, **kwargs) -> None:
            try:
                super().__init__(*args, **kwargs)
            except BaseException:
                # pymavlink opens the file first: a log it cannot index would leave it open
                # (a ResourceWarning wherever the collector runs next). Its map may still be
                # referenced by the indexer's arrays: the collector frees it with them.
                if getattr(self, "filehandle", None) is not None:
                    self.filehandle.close()
                raise

        def init_clock(self) -> None:
            """The streams keep the log's own TimeUS/SampleUS: pymavlink's search for a GPS
            time base (every message decoded, in Python, when the GPS has no fix, as on a
            bench) is not needed; its microsecond clock is set instead."""
            self._rewind(keep_messages=True)
            self.init_clock_usec()

    log = Reader(str(path), zero_time_base=True)
    try:
        present = {n for n, i in log.name_to_id.items() if log.counts[i] > 0}
        wanted = [n for n in DATAFLASH if n in present]
        formats = {n: log.formats[log.name_to_id[n]] for n in wanted}
        # a type without an instance field is one stream set: ask keep before decoding it
        wanted = [n for n in wanted if "I" in formats[n].colhash or keep is None or keep(n)]
        notes: list[str] = []
        tables = {n: _decode_indexed(log, formats[n]) for n in wanted} if fast else {}
        slow = [n for n in wanted if tables.get(n) is None]
        by_type: dict[str, list] = {n: [] for n in slow}
        if slow:
            log.rewind()
            while (m := log.recv_match(type=set(slow), strict=True)) is not None:
                by_type[m.fmt.name].append(m._elements)
        for n, rows in by_type.items():
            tables[n] = _table(rows, dict(formats[n].colhash), _needed(DATAFLASH[n]))
        # where the last message pymavlink's index found ends, against the file's end
        ends = [(log.offsets[i][-1] + log.formats[i].len, log.formats[i].name)
                for i in range(256) if log.counts[i] > 0 and i in log.formats]
        end, last = max(ends, default=(0, ""))
        if end > log.data_len:
            notes.append(f"truncated: the file ends inside its last message ({last}, at byte "
                         f"{end - log.formats[log.name_to_id[last]].len}); read up to there")
        elif 0 < end < log.data_len:
            notes.append(f"{plural(log.data_len - end, 'byte')} after the last whole message "
                         "start no message (the log may be cut short)")
    finally:
        log.filehandle.close()
    found: dict[str, _Rows] = {}
    for n in wanted:
        fmt, got = formats[n], tables[n]
        notes.extend(_unit_check(n, fmt))
        for c, j in got.columns.items():
            mult = fmt.msg_mults[fmt.colhash[c]]
            if mult is not None:  # as pymavlink's DFMessage applies it: 0.01 as / 100
                got.table[:, j] = (got.table[:, j] / (1 / mult) if 0 < mult < 1 else
                                   got.table[:, j] * mult)
        if "I" not in got.columns:
            found[n] = got
            continue
        inst_col = got.table[:, got.columns["I"]]
        for inst in np.unique(inst_col).astype(int).tolist():
            label = f"{n}[{inst}]"
            if keep is None or keep(label):
                found[label] = _Rows(got.columns, got.table[inst_col == inst])
    return found, present, notes


_STRUCT_NP = {"Q": "<u8", "q": "<i8", "d": "<f8", "f": "<f4", "e": "<f2", "I": "<u4",
              "i": "<i4", "H": "<u2", "h": "<i2", "B": "u1", "b": "i1"}
_CHUNK = 1 << 16  # messages gathered at once (an index array of 8 bytes per byte copied)


def _record_dtype(fmt) -> np.dtype | None:
    """The packed numpy record of a DataFlash format (``DFFormat.msg_struct``), columns named
    ``c0``, ``c1``, ...; None for a layout numpy cannot view (arrays, odd lengths)."""
    import re

    tokens = re.findall(r"(\d*)([A-Za-z?])", fmt.msg_struct.lstrip("<"))
    fields = []
    for i, (count, char) in enumerate(tokens):
        if char == "s":
            fields.append((f"c{i}", f"S{count or 1}"))
        elif char in _STRUCT_NP and not count:
            fields.append((f"c{i}", _STRUCT_NP[char]))
        else:
            return None
    dtype = np.dtype(fields)
    return dtype if dtype.itemsize == fmt.len - 3 and len(fields) == len(fmt.columns) else None


def _decode_indexed(log, fmt) -> _Rows | None:
    """The needed columns of every message of ``fmt`` that pymavlink's index lists and the
    file holds whole, without a Python step per message."""
    dtype = _record_dtype(fmt)
    if dtype is None:
        return None
    offsets = np.asarray(log.offsets[fmt.type], dtype=np.int64)
    offsets = offsets[offsets + fmt.len <= log.data_len]  # a cut last message: as recv_match
    data = np.frombuffer(log.data_map, dtype=np.uint8)
    width = fmt.len - 3
    raw = np.empty((len(offsets), width), dtype=np.uint8)
    step = np.arange(width)
    for a in range(0, len(offsets), _CHUNK):
        raw[a:a + _CHUNK] = data[(offsets[a:a + _CHUNK] + 3)[:, None] + step]
    del data  # the mmap stays closable
    records = raw.view(dtype).ravel()
    keep = sorted(c for c in _needed(DATAFLASH[fmt.name]) if c in fmt.colhash)
    table = np.empty((len(records), len(keep)))
    for j, c in enumerate(keep):
        table[:, j] = records[f"c{fmt.colhash[c]}"]
    return _Rows({c: j for j, c in enumerate(keep)}, table)


# The units ArduPilot's FMTU states for the columns read (pymavlink's unit names, the
# multiplier's prefix included), where a log has FMTU messages.
_FMTU_UNITS = {"AccX": "m/s/s", "GyrX": "rad/s", "MagX": "mGauss", "T": "degC"}


def _unit_check(name: str, fmt) -> list[str]:
    """A note where the log's own unit for a column read differs from the one assumed."""
    if not fmt.units:
        return []
    out = []
    for col, unit in _FMTU_UNITS.items():
        if col in fmt.colhash and fmt.units[fmt.colhash[col]] not in ("", unit):
            out.append(f"{name}: the log states {col} in {fmt.units[fmt.colhash[col]]!r}; "
                       f"read as {unit!r} (ArduPilot's unit for it)")
    return out


def _read_tlog(path: Path, keep: Callable[[str], bool] | None):
    """pymavlink's telemetry-log reader (8-byte time, then a MAVLink 1 or 2 frame): the wanted
    message types, each message's fields collected in order; a type sent by several
    systems/components is one stream per sender (``SCALED_IMU@1/1``)."""
    from pymavlink import mavutil

    log = mavutil.mavlogfile(str(path), robust_parsing=True)
    present: set[str] = set()
    found: dict[str, _Rows] = {}
    raw: dict[tuple[str, int, int], list] = {}
    columns: dict[str, dict[str, int]] = {}
    try:
        while (m := log.recv_msg()) is not None:
            t = m.get_type()
            present.add(t)
            if t not in TLOG:
                continue
            if t not in columns:
                columns[t] = {c: i for i, c in enumerate(m.get_fieldnames())}
                columns[t]["_receive"] = len(columns[t])
            raw.setdefault((t, m.get_srcSystem(), m.get_srcComponent()), []).append(
                [getattr(m, c) for c in m.get_fieldnames()] + [m._timestamp])
    finally:
        log.close()
    senders: dict[str, int] = {}
    for t, _, _ in raw:
        senders[t] = senders.get(t, 0) + 1
    for (t, sysid, compid), rows in raw.items():
        label = t if senders[t] == 1 else f"{t}@{sysid}/{compid}"
        if keep is None or keep(label):
            found[label] = _table(rows, columns[t], _needed(TLOG[t]) | {"_receive"})
    notes = []
    if "BAD_DATA" in present:
        present.discard("BAD_DATA")
        notes.append("corrupt stretches: pymavlink found bytes that form no valid MAVLink "
                     "message (skipped)")
    return found, present, notes


def _streams(instance: str, layout: _Layout, rows: _Rows, key: str,
             notes: list[str]) -> list[Stream]:
    if not len(rows.table):
        return []
    table = rows.table
    clock = next((c for c in layout.clock if c in rows.columns), None)
    if clock is None:
        notes.append(f"{instance}: no clock column ({', '.join(layout.clock)}); not read")
        return []
    t = table[:, rows.columns[clock]]
    time_source = {"TimeUS": "TimeUS (µs since boot, when logged)",
                   "SampleUS": "SampleUS (µs since boot, when sampled)",
                   "time_boot_ms": "time_boot_ms (ms since boot)",
                   "time_usec": "time_usec (µs since boot or Unix epoch, as the sender sets)"}[
        clock]
    local: list[str] = []
    if key == "tlog" and not t.any():
        t = table[:, rows.columns["_receive"]] * layout.clock_units
        time_source = "the tlog's receive time (the message's own time is zero)"
        local.append(f"{instance}: {clock} is zero throughout; the tlog's receive time is used")
    ts, order = in_time_order(t, instance, local)
    seconds = ts / layout.clock_units
    notes.extend(local)
    origin_base = f"{FORMAT_NAMES[key]} message {instance}"
    kinds = {tr.kind for tr in layout.triads}
    imu = instance if {"acc", "gyro"} <= kinds else _imu_of(instance)
    out: list[Stream] = []
    for triad in layout.triads:
        if any(c not in rows.columns for c in triad.columns):
            continue
        values = table[:, [rows.columns[c] for c in triad.columns]][order]
        if triad.scale != 1.0:
            values = values / triad.scale
        if triad.kind == "mag" and key == "tlog" and not values.any():
            continue  # a sender without a compass fills zeros
        out.append(Stream(triad.kind, instance, seconds, values, triad.unit,
                          f"{origin_base}, fields {', '.join(triad.columns)}", AP_FRAME,
                          time_source, None, imu if triad.kind != "mag" else None,
                          tuple(x for x in (layout.note,) if x)))
    if layout.temp and layout.temp[0] in rows.columns:
        temp = table[order, rows.columns[layout.temp[0]]] / layout.temp[1]
        present = temp != 0 if layout.temp_zero_is_missing else np.isfinite(temp)
        if present.any():
            out.append(Stream("temp", instance, seconds[present], temp[present, None], "degC",
                              f"{origin_base}, field {layout.temp[0]}", None, time_source,
                              None, imu))
    return out


def _imu_of(instance: str) -> str:
    """ACC[1] and GYR[1] (or ACC2 and GYR2) are one IMU's: both are named ``ACC[1]+GYR[1]``."""
    for a, g in (("ACC", "GYR"), ("GYR", "ACC")):
        if instance.startswith(a):
            rest = instance[len(a):]
            acc, gyr = (instance, g + rest) if a == "ACC" else (g + rest, instance)
            return f"{acc}+{gyr}"
    return instance


def _one_line(err: BaseException) -> str:
    text = " ".join(str(err).split()) or type(err).__name__
    return text if len(text) <= 200 else text[:197] + "..."
