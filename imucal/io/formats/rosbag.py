"""ROS 1 bags, ROS 2 bags (a ``.db3`` SQLite file, an ``.mcap`` file, or a bag directory with
``metadata.yaml``) and MCAP files, read with ``rosbags``: every ``sensor_msgs/msg/Imu``,
``MagneticField`` and ``Temperature`` topic becomes streams (an Imu topic gives an ``acc`` and a
``gyro`` stream; method.md §0: a stream is the sensor as the source states it).

Speed: rosbags' per-message deserializer costs tens of microseconds a message. These three
messages have a fixed layout once the length of ``header.frame_id`` is known, so the raw bytes
of a topic are grouped by message length into (messages, bytes) matrices and each field read
as a strided column (:func:`_layout` computes the offsets from the typestore's own message
definition: CDR alignment for ROS 2, packed little-endian for ROS 1). rosbags' deserializer
stays the reference (tests compare the two) and the fallback for whatever the fast path does
not cover (a big-endian CDR message, an unexpected length, a message type with a sequence).

Storage is opened by rosbags and read the way rosbags reads it, with less per-message
Python: a ``.db3`` by windows of SQL aggregates over the selected topics, an indexed MCAP file
and a ROS 1 bag chunk by chunk through their indexes (numpy gathers the message records), a
bag of zstd-compressed messages or an unindexed MCAP through rosbags' ``messages()``. Only the
topics ``keep`` accepts are read at all; memory follows them, not the file.
"""

from __future__ import annotations

import hashlib
import itertools
import struct
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from imucal.errors import ImucalError, plural
from imucal.io.formats.clock import in_time_order
from imucal.streams import Stream, StreamSet

IMU = "sensor_msgs/msg/Imu"
MAG = "sensor_msgs/msg/MagneticField"
TEMP = "sensor_msgs/msg/Temperature"
# message type -> (kind, the message's field, its covariance field or None, unit)
SENSORS: dict[str, tuple[tuple[str, str, str | None, str], ...]] = {
    IMU: (("acc", "linear_acceleration", "linear_acceleration_covariance", "m/s^2"),
          ("gyro", "angular_velocity", "angular_velocity_covariance", "rad/s")),
    # sensor_msgs/MagneticField states tesla; sensor_msgs/Temperature degrees Celsius.
    MAG: (("mag", "magnetic_field", None, "T"),),
    TEMP: (("temp", "temperature", None, "degC"),),
}
# REP 103: a body frame is x forward, y left, z up. It is the convention ROS states; nothing in
# a bag proves a driver followed it.
FRAME = "FLU (ROS REP 103)"
FORMAT_NAMES = {"ros1": "ROS 1 bag", "ros2": "ROS 2 bag", "mcap": "MCAP"}
_VECTOR = ("x", "y", "z")
_SIZES = {"bool": 1, "byte": 1, "char": 1, "int8": 1, "uint8": 1, "int16": 2, "uint16": 2,
          "int32": 4, "uint32": 4, "int64": 8, "uint64": 8, "float32": 4, "float64": 8}
_DTYPES = {"bool": "u1", "byte": "u1", "char": "u1", "int8": "i1", "uint8": "u1", "int16": "<i2",
           "uint16": "<u2", "int32": "<i4", "uint32": "<u4", "int64": "<i8", "uint64": "<u8",
           "float32": "<f4", "float64": "<f8"}
_CHUNK = 1 << 20


class _NotFixed(Exception):
    """The message cannot be read by offsets (a sequence, a second string, an odd length)."""


# --- layout: where each field sits, from the typestore's message definition -----------------

def _layout(fielddefs: dict[str, Any], msgtype: str, strlen: int | None, cdr: bool,
            ) -> tuple[dict[str, tuple[int, str, int]], int]:
    """``path -> (byte offset, numpy dtype, count)`` of every primitive field of ``msgtype``
    and the message's length, for a message whose one string (``header.frame_id``) has the
    wire length ``strlen`` (None: stop at the string, giving the offset of its length prefix).

    CDR (ROS 2): 4 bytes of encapsulation header, then each primitive aligned to its size
    counted from after that header, a string as uint32 length (with its NUL) and bytes. ROS 1:
    packed, a string's length without a NUL."""
    base = 4 if cdr else 0
    out: dict[str, tuple[int, str, int]] = {}
    pos = 0
    strings = 0

    def align(n: int) -> None:
        nonlocal pos
        if cdr:
            pos += -pos % n

    def walk(typ: str, prefix: str) -> bool:
        nonlocal pos, strings
        for name, (node, detail) in fielddefs[typ][1]:
            path = f"{prefix}{name}"
            if node == 1:  # a primitive or a string
                tname = detail[0]
                if tname == "string":
                    align(4)
                    out[path + "#len"] = (base + pos, "<u4", 1)
                    strings += 1
                    if strlen is None:
                        return False
                    if strings > 1:
                        raise _NotFixed(f"{msgtype} holds more than one string")
                    pos += 4
                    out[path] = (base + pos, "u1", strlen)
                    pos += strlen
                    continue
                if tname not in _SIZES:
                    raise _NotFixed(f"{msgtype}.{path} is a {tname}")
                align(_SIZES[tname])
                out[path] = (base + pos, _DTYPES[tname], 1)
                pos += _SIZES[tname]
            elif node == 2:  # a nested message
                if not walk(detail, path + "."):
                    return False
            elif node == 3 and detail[0][0] == 1 and detail[0][1][0] in _SIZES:
                tname, count = detail[0][1][0], detail[1]
                align(_SIZES[tname])
                out[path] = (base + pos, _DTYPES[tname], count)
                pos += _SIZES[tname] * count
            else:
                raise _NotFixed(f"{msgtype}.{path} has no fixed length")
        return True

    walk(msgtype, "")
    return out, base + pos


# --- raw messages of one topic ------------------------------------------------------------

@dataclass
class _Topic:
    """A selected topic and its messages gathered so far: (receive times, rows) pieces where
    rows is a (messages, bytes) uint8 matrix of messages of one length, and messages read
    one by one (``loose``) where a storage gave them so."""

    name: str
    msgtype: str
    pieces: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    loose: list[tuple[int, bytes]] = field(default_factory=list)  # read one by one (fallback)

    def add_blobs(self, recv: np.ndarray, blobs: list[bytes]) -> None:
        """Messages as a list of bytes: one matrix per message length, joined in C."""
        if not blobs:
            return
        lengths = np.fromiter(map(len, blobs), np.int64, len(blobs))
        for length in np.unique(lengths):
            sel = lengths == length
            part = blobs if sel.all() else list(itertools.compress(blobs, sel.tolist()))
            rows = np.frombuffer(b"".join(part), np.uint8).reshape(len(part), int(length))
            self.pieces.append((recv[sel], rows))

    def add_joined(self, recv: np.ndarray, joined: bytes, lengths: np.ndarray) -> None:
        """Messages laid end to end in one bytes object: a (messages, bytes) matrix with no
        copy when they are all one length (the usual case), else gathered per length."""
        buf = np.frombuffer(joined, np.uint8)
        if len(lengths) and (lengths == lengths[0]).all():
            self.pieces.append((recv, buf.reshape(len(lengths), int(lengths[0]))))
            return
        starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
        self.add_slices(recv, buf, starts, lengths)

    def add_slices(self, recv: np.ndarray, buf: np.ndarray, starts: np.ndarray,
                   lengths: np.ndarray) -> None:
        """Messages as slices of one buffer (an MCAP chunk): gathered per message length."""
        for length in np.unique(lengths):
            sel = lengths == length
            at = starts[sel]
            step = np.diff(at)
            if len(at) > 1 and step[0] >= length and (step == step[0]).all():
                # Evenly spaced (one channel, or channels in turn): a view, no copy.
                rows = np.lib.stride_tricks.as_strided(
                    buf[at[0]:], (len(at), int(length)), (int(step[0]), 1), writeable=False)
                if buf.nbytes > 2 * rows.size:
                    # A view keeps its whole chunk alive: copied when the chunk is mostly
                    # other topics, so memory follows the selected topics, not the file.
                    rows = np.ascontiguousarray(rows)
            else:
                rows = buf[at[:, None] + np.arange(int(length))]
            self.pieces.append((recv[sel], rows))


# --- reading the storages ------------------------------------------------------------------

def _rosbags_messages(reader: Any, conns: list[Any], topics: dict[str, _Topic]) -> None:
    """Any storage through rosbags' own ``messages()`` (ROS 1 chunks, compressed messages,
    unindexed MCAP): one Python step per message, the bytes kept as they come."""
    recv: dict[str, list[int]] = {}
    blobs: dict[str, list[bytes]] = {}
    with _rosbags_internals():
        for conn, stamp, raw in reader.messages(connections=conns):
            recv.setdefault(conn.topic, []).append(stamp)
            blobs.setdefault(conn.topic, []).append(bytes(raw))
    for name, b in blobs.items():
        topics[name].add_blobs(np.asarray(recv[name], np.int64), b)


def _ros1_messages(reader: Any, conns: list[Any], topics: dict[str, _Topic]) -> None:
    """A ROS 1 bag chunk by chunk through the index rosbags read at open (time, chunk and
    offset of every message of a connection): numpy reads the message data records of a
    chunk; rosbags reads the bag where a record is not laid out as the first one of its
    header length (then nothing here is trusted)."""
    wanted = {c.id: c.topic for c in conns}
    parts = [np.fromiter(itertools.chain.from_iterable(reader.indexes[cid]), np.int64,
                         3 * len(reader.indexes[cid])).reshape(-1, 3)
             for cid in wanted]
    cids = np.concatenate([np.full(len(p), cid) for p, cid in zip(parts, wanted)])
    index = np.concatenate(parts) if parts else np.zeros((0, 3), np.int64)
    # Held until every chunk is read: one record out of layout sends the whole bag to
    # rosbags. The pieces hold only the selected messages' bytes (add_slices copies them out
    # of a chunk that is mostly other topics).
    found = _Topic("", "")
    owner: list[int] = []
    # Grouped by chunk, then connection, in offset order: one pass, one decompression each.
    order = np.lexsort((index[:, 2], cids, index[:, 1]))
    index, cids = index[order], cids[order]
    cut = np.flatnonzero((np.diff(index[:, 1]) != 0) | (np.diff(cids) != 0)) + 1
    bounds = zip(np.r_[0, cut].tolist(), np.r_[cut, len(index)].tolist())
    buf, loaded = np.zeros(0, np.uint8), -1
    try:
        for lo, hi in bounds if len(index) else ():
            pos, cid = int(index[lo, 1]), int(cids[lo])
            if pos != loaded:
                chunk = reader.chunks[pos]
                reader.bio.seek(chunk.datapos)
                buf = np.frombuffer(chunk.decompressor(reader.bio.read(chunk.datasize)),
                                    np.uint8)
                loaded = pos
            part = index[lo:hi]
            starts, lengths = _ros1_records(buf, part[:, 2], part[:, 0], cid)
            before = len(found.pieces)
            found.add_slices(part[:, 0], buf, starts, lengths)
            owner.extend([cid] * (len(found.pieces) - before))
    except _NotFixed:
        _rosbags_messages(reader, conns, topics)
        return
    for cid, piece in zip(owner, found.pieces):
        topics[wanted[cid]].pieces.append(piece)


def _ros1_records(buf: np.ndarray, off: np.ndarray, time: np.ndarray, cid: int,
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Where the data of each message data record at ``off`` starts, and its length. A record
    is a uint32 header length, the header (fields ``len name=value``: op, conn, time in any
    order), a uint32 data length and the data; each header must match the first one's bytes
    except its time, hold op 0x02, this connection and the index's time."""
    if not len(off):
        return off, off
    if off.min() < 0 or off.max() + 4 > len(buf):
        raise _NotFixed("an index offset is outside its chunk")
    hl = _u32(buf, off)
    if (hl != hl[0]).any() or off.max() + 8 + int(hl[0]) > len(buf):
        raise _NotFixed("message headers of several lengths")
    n = int(hl[0])
    head = buf[off[:, None] + 4 + np.arange(n)]
    fields: dict[bytes, int] = {}
    first, at = bytes(head[0]), 0
    while at + 4 <= n:
        size = int.from_bytes(first[at:at + 4], "little")
        name, sep, _ = first[at + 4:at + 4 + size].partition(b"=")
        if not sep or at + 4 + size > n:
            raise _NotFixed("a header field does not parse")
        fields[name] = at + 4 + len(name) + 1
        at += 4 + size
    if at != n or not {b"op", b"conn", b"time"} <= set(fields):
        raise _NotFixed("not a message data header")
    varying = np.zeros(n, bool)
    varying[fields[b"time"]:fields[b"time"] + 8] = True
    if not (head[:, ~varying] == head[0, ~varying]).all() or head[0, fields[b"op"]] != 0x02 \
            or _u32(head[0], np.array([fields[b"conn"]]))[0] != cid:
        raise _NotFixed("a header differs from the first")
    t = fields[b"time"]
    stamp = (_u32(head, None, t).astype(np.int64) * 1_000_000_000
             + _u32(head, None, t + 4).astype(np.int64))
    if (stamp != time).any():
        raise _NotFixed("a record's time differs from its index entry")
    dl = _u32(buf, off + 4 + n)
    starts = off + 8 + n
    if (starts + dl > len(buf)).any():
        raise _NotFixed("a message runs past its chunk")
    return starts, dl.astype(np.int64)


def _u32(buf: np.ndarray, at: np.ndarray | None, col: int = 0) -> np.ndarray:
    """Little-endian uint32 at byte offsets ``at`` of a 1-D buffer, or at column ``col`` of
    every row of a 2-D one."""
    if at is None:
        return buf[:, col:col + 4].copy().view("<u4")[:, 0]
    return buf[at[:, None] + np.arange(4)].copy().view("<u4")[:, 0]


_SQL_WINDOW = 1 << 17  # message rows (of every topic) per query: bounds what one query holds


def _sqlite_messages(storage: Any, conns: list[Any], topics: dict[str, _Topic]) -> None:
    """A .db3 file in windows of row ids, one query each for all selected topics: SQLite
    concatenates a topic's messages, times and lengths itself (group_concat; one aggregate
    walks the rows in one order for all three), so no Python object is made per message.
    Where that cannot be trusted (a UTF-16 database, where text is converted; lengths that do
    not add up), rows are fetched one by one."""
    db = storage.dbconn
    ids = {c.id: c.topic for c in conns}
    marks = ",".join("?" * len(ids))
    ((encoding,),) = db.execute("PRAGMA encoding").fetchall()
    ((lo,),) = db.execute("SELECT min(id) FROM messages").fetchall()
    while lo is not None:
        window = (lo, lo + _SQL_WINDOW, *ids)
        # The next window starts at the next row that exists (ids may have gaps): a lookup
        # in the rowid tree, not a scan.
        ((lo,),) = db.execute("SELECT min(id) FROM messages WHERE id >= ?",
                              (lo + _SQL_WINDOW,)).fetchall()
        if encoding == "UTF-8":
            rows = db.execute(
                "SELECT topic_id, CAST(group_concat(data, x'') AS BLOB), "
                "group_concat(timestamp), group_concat(length(data)), count(*) FROM messages "
                f"WHERE id >= ? AND id < ? AND topic_id IN ({marks}) GROUP BY topic_id",
                window).fetchall()
            parsed = [(tid, blob, np.fromstring(ts, np.int64, sep=","),
                       np.fromstring(lens, np.int64, sep=","), count)
                      for tid, blob, ts, lens, count in rows]
            if all(len(t) == len(n) == count and int(n.sum()) == len(blob)
                   for _, blob, t, n, count in parsed):
                for tid, blob, stamps, lengths, _ in parsed:
                    topics[ids[tid]].add_joined(stamps, blob, lengths)
                continue
        for tid, stamp, data in db.execute(
                "SELECT topic_id, timestamp, data FROM messages "
                f"WHERE id >= ? AND id < ? AND topic_id IN ({marks})", window):
            topics[ids[tid]].loose.append((stamp, data))


def _mcap_messages(storage: Any, conns: list[Any], topics: dict[str, _Topic]) -> None:
    """An indexed MCAP file chunk by chunk: each chunk's message index (log time and offset
    of every message of a channel) says where the records are; numpy reads them. Where the
    indexes miss messages the file's statistics count, the file is scanned by rosbags."""
    from rosbags.rosbag2.storage_mcap import decompress  # validates size and CRC

    bio = storage.bio
    by_id = {c.id: c for c in conns}
    indexed = {cid: sum(ch.channel_count.get(cid, 0) for ch in storage.chunks) for cid in by_id}
    if any(c.msgcount and indexed[cid] != c.msgcount for cid, c in by_id.items()):
        _rosbags_messages(_Scan(storage), conns, topics)
        return
    for chunk in storage.chunks:
        wanted = [cid for cid in chunk.message_index_offsets if cid in by_id]
        if not wanted:
            continue
        bio.seek(chunk.chunk_start_offset + 9 + 24)
        (crc,) = struct.unpack("<I", bio.read(4))
        bio.seek(chunk.chunk_start_offset + 9 + 40 + len(chunk.compression))
        raw = decompress(bio.read(chunk.compressed_size), chunk.compression,
                         chunk.uncompressed_size, crc)
        buf = np.frombuffer(raw, np.uint8)
        for cid in wanted:
            bio.seek(chunk.message_index_offsets[cid])
            op, _, channel, size = struct.unpack("<BQHI", bio.read(15))
            if op != 0x07 or channel != cid or size % 16:
                raise _Corrupt(f"MCAP message index at byte {chunk.message_index_offsets[cid]} "
                               "is not one")
            index = np.frombuffer(bio.read(size), "<u8").reshape(-1, 2).astype(np.int64)
            if not len(index):
                continue
            off = index[:, 1]
            if off.min() < 0 or off.max() + 31 > len(buf):
                raise _Corrupt("an MCAP message index points past its chunk")
            # Message record: opcode 0x05, uint64 length, uint16 channel, uint32 sequence,
            # uint64 log time, uint64 publish time, then the message's bytes.
            head = buf[off[:, None] + np.arange(31)]
            rec_len = head[:, 1:9].copy().view("<u8")[:, 0].astype(np.int64)
            chan = head[:, 9:11].copy().view("<u2")[:, 0]
            if (head[:, 0] != 0x05).any() or (chan != cid).any() or (rec_len < 22).any() \
                    or (off + 9 + rec_len > len(buf)).any():
                raise _Corrupt("an MCAP message index does not point at its messages")
            topics[by_id[cid].topic].add_slices(index[:, 0], buf, off + 31, rec_len - 22)


@dataclass
class _Scan:
    """An MCAP storage read record by record by rosbags, ignoring its indexes."""

    storage: Any

    def messages(self, connections: list[Any]) -> Any:
        return self.storage.messages_scan(connections)


class _Corrupt(Exception):
    """The file's own structure is broken (turned into an ImucalError naming the file)."""


@contextmanager
def _rosbags_internals() -> Iterator[None]:
    """Inside rosbags' readers, a corrupt ROS 1 bag surfaces as the lookup or assertion
    that failed on it (a KeyError on a connection id read from garbage): those become
    :class:`_Corrupt` here, where only rosbags runs, and stay bugs anywhere else."""
    try:
        yield
    except (KeyError, AssertionError, IndexError, ValueError) as err:
        raise _Corrupt(f"{type(err).__name__} in rosbags: {err}") from err


def _open(path: Path, key: str) -> tuple[Any, list[Any]]:
    """rosbags' reader for the format sniffed from the file's bytes, and the storage files
    behind it for the fast paths (none: read through rosbags' ``messages()``). rosbags' own
    Reader picks a single file's storage by its suffix; here the magic decides, so a renamed
    file reads the same."""
    if key == "ros1":
        from rosbags.rosbag1 import Reader as Reader1
        return Reader1(path), []
    if path.is_dir():
        from rosbags.rosbag2 import Reader as Reader2
        reader = Reader2(path)
        return reader, [reader.storage]
    from rosbags.rosbag2.storage_mcap import McapReader
    from rosbags.rosbag2.storage_sqlite3 import Sqlite3Reader
    storage = (McapReader if key == "mcap" else Sqlite3Reader)(path)
    return storage, [storage]


def _files(storages: list[Any]) -> list[Any]:
    """The storage files, once open: a bag directory's own (unless each message is
    compressed, which rosbags undoes)."""
    out = []
    for storage in storages:
        if hasattr(storage, "storages"):  # a bag directory
            if storage.metadata.compression_mode != "message":
                out.extend(storage.storages)
        else:
            out.append(storage)
    return out


def _gather(reader: Any, storages: list[Any], selected: list[Any], topics: dict[str, _Topic],
            ) -> None:
    from rosbags.rosbag2.storage_mcap import McapReader
    from rosbags.rosbag2.storage_sqlite3 import Sqlite3Reader

    storages = _files(storages)
    if not storages:
        if hasattr(reader, "indexes") and hasattr(reader, "chunks"):  # a ROS 1 bag
            _ros1_messages(reader, selected, topics)
        else:
            _rosbags_messages(reader, selected, topics)
        return
    wanted = {(c.topic, c.msgtype) for c in selected}
    for storage in storages:
        conns = [c for c in storage.connections if (c.topic, c.msgtype) in wanted]
        if not conns:
            continue
        if isinstance(storage, Sqlite3Reader):
            _sqlite_messages(storage, conns, topics)
        elif isinstance(storage, McapReader) and storage.chunks:
            _mcap_messages(storage, conns, topics)
        else:
            _rosbags_messages(storage, conns, topics)


# --- decoding -----------------------------------------------------------------------------

@dataclass
class _Decoded:
    """One topic's messages decoded: header stamps and receive times (ns), each wanted
    field's values, and the frame_ids seen."""

    stamp: np.ndarray
    recv: np.ndarray
    fields: dict[str, np.ndarray]
    frame_ids: list[str]


def _wanted(msgtype: str) -> dict[str, tuple[str, ...]]:
    """Field name -> the primitive paths that make its columns."""
    out: dict[str, tuple[str, ...]] = {}
    for _, fname, cov, _ in SENSORS[msgtype]:
        out[fname] = tuple(f"{fname}.{a}" for a in _VECTOR) if fname != "temperature" \
            else ("temperature",)
        if cov:
            out[cov] = (cov,)  # element 0 only: -1 there marks the field absent
    return out


def _stamp_paths(fielddefs: dict[str, Any]) -> tuple[str, str]:
    names = [n for n, _ in fielddefs["builtin_interfaces/msg/Time"][1]]
    return f"header.stamp.{names[0]}", f"header.stamp.{names[1]}"  # sec, nanosec (ROS 1: nsec)


def _column(rows: np.ndarray, where: tuple[int, str, int]) -> np.ndarray:
    """One field of every row, (messages, count): a view of the matrix's columns (rows may
    be a strided view of a chunk; each row's bytes are contiguous, so the view is allowed)."""
    off, dtype, count = where
    dt = np.dtype(dtype)
    return rows[:, off:off + dt.itemsize * count].view(dt)


def _field(rows: np.ndarray, where: dict[str, tuple[int, str, int]], paths: tuple[str, ...],
           ) -> np.ndarray:
    """A field's columns as float64, (messages, k): one slice where its primitives sit side
    by side (x, y, z of a Vector3), else stacked."""
    first = where[paths[0]]
    if paths[0].endswith("_covariance"):
        return _column(rows, (first[0], first[1], 1)).astype(np.float64)  # element 0 only
    dt = np.dtype(first[1])
    side_by_side = all(where[p][1] == first[1] and where[p][0] == first[0] + i * dt.itemsize
                       for i, p in enumerate(paths))
    if side_by_side:
        return _column(rows, (first[0], first[1], first[2] * len(paths))).astype(np.float64)
    return np.hstack([_column(rows, where[p]) for p in paths]).astype(np.float64)


def _decode_rows(rows: np.ndarray, fielddefs: dict[str, Any], msgtype: str, cdr: bool,
                 ) -> list[tuple[np.ndarray, np.ndarray, dict[str, np.ndarray], list[str]]]:
    """Messages of one length decoded by offsets: (row selection, header stamps in ns, the
    wanted fields, the frame_ids) per frame_id length. Raises _NotFixed where offsets cannot
    read them."""
    n, length = rows.shape
    if cdr and length >= 2:
        # Encapsulation header: 0x00 0x01 is little-endian CDR (0x00 0x00 big-endian).
        if (rows[:, 0] != 0).any() or (rows[:, 1] != 1).any():
            raise _NotFixed("not little-endian CDR")
    head, _ = _layout(fielddefs, msgtype, None, cdr)
    (len_at, _, _), = [v for k, v in head.items() if k.endswith("#len")]
    if len_at + 4 > length:
        raise _NotFixed("shorter than its header")
    strlens = _column(rows, (len_at, "<u4", 1))[:, 0]
    sec, nsec = _stamp_paths(fielddefs)
    out = []
    for strlen in np.unique(strlens):
        sel = strlens == strlen
        part = rows if sel.all() else rows[sel]
        where, total = _layout(fielddefs, msgtype, int(strlen), cdr)
        # FastCDR pads a message to a multiple of 4 bytes; nothing else may follow.
        if not total <= length <= total + (3 if cdr else 0):
            raise _NotFixed(f"{length} bytes where the definition gives {total}")
        stamp = (_column(part, where[sec])[:, 0].astype(np.int64) * 1_000_000_000
                 + _column(part, where[nsec])[:, 0].astype(np.int64))
        fields = {name: _field(part, where, paths) for name, paths in _wanted(msgtype).items()}
        s_off, _, s_len = where["header.frame_id"]
        ids = part[:, s_off:s_off + s_len - (1 if cdr and s_len else 0)]  # CDR: a final NUL
        uniq = [ids[0]] if (ids == ids[0]).all() else list(np.unique(ids, axis=0))
        out.append((sel, stamp, fields, [bytes(u).decode("utf-8", "replace") for u in uniq]))
    return out


def _decode_reference(raws: Iterable[tuple[int, bytes]], typestore: Any, msgtype: str,
                      cdr: bool) -> _Decoded:
    """rosbags' own deserializer, message by message: the reference and the fallback."""
    deser = typestore.deserialize_cdr if cdr else typestore.deserialize_ros1
    stamps, recv, frames = [], [], []
    fields: dict[str, list[Any]] = {name: [] for name in _wanted(msgtype)}
    for t, raw in raws:
        msg = deser(raw, msgtype)
        stamps.append(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
        recv.append(t)
        frames.append(msg.header.frame_id)
        for name in fields:
            value = getattr(msg, name)
            fields[name].append([value[0]] if name.endswith("_covariance")
                                else [value] if name == "temperature"
                                else [value.x, value.y, value.z])
    width = {name: len(paths) for name, paths in _wanted(msgtype).items()}
    return _Decoded(np.asarray(stamps, np.int64), np.asarray(recv, np.int64),
                    {k: np.asarray(v, np.float64).reshape(-1, width[k])
                     for k, v in fields.items()},
                    list(dict.fromkeys(frames)))


def _decode(topic: _Topic, typestore: Any, cdr: bool, fast: bool) -> _Decoded:
    """A topic's pieces decoded by offsets where the layout allows, else by rosbags."""
    fielddefs = typestore.fielddefs
    parts: list[_Decoded] = []
    slow: list[tuple[int, bytes]] = list(topic.loose)
    for recv, rows in topic.pieces:
        if not fast:
            slow.extend(zip(recv.tolist(), map(bytes, rows)))
            continue
        try:
            decoded = _decode_rows(rows, fielddefs, topic.msgtype, cdr)
        except _NotFixed:
            slow.extend(zip(recv.tolist(), map(bytes, rows)))
            continue
        for sel, stamp, fields, frames in decoded:
            parts.append(_Decoded(stamp, recv if sel.all() else recv[sel], fields, frames))
    if slow:
        parts.append(_decode_reference(slow, typestore, topic.msgtype, cdr))
    if len(parts) == 1:
        return parts[0]
    names = list(_wanted(topic.msgtype))
    return _Decoded(np.concatenate([p.stamp for p in parts]),
                    np.concatenate([p.recv for p in parts]),
                    {k: np.concatenate([p.fields[k] for p in parts]) for k in names},
                    list(dict.fromkeys(f for p in parts for f in p.frame_ids)))


# --- streams ------------------------------------------------------------------------------

def _clock(topic: str, d: _Decoded) -> tuple[np.ndarray, str, list[str], np.ndarray]:
    """Header stamps, or the receive time where every stamp of the topic is zero; sorted,
    exact repeats dropped. Returns (ns, time source, notes, the order to take samples in)."""
    notes: list[str] = []
    rows = np.arange(len(d.stamp))
    if len(d.stamp) and not d.stamp.any():
        ns, source = d.recv, "receive time (the bag's record time; every header stamp is zero)"
        notes.append(f"{topic}: every header.stamp is zero; the bag's receive time is used")
    else:
        ns, source = d.stamp, "header.stamp"
        unset = ns == 0
        if unset.any():  # a driver not yet synchronised: a zero stamp is "not set", not 1970
            notes.append(f"{topic}: {plural(int(unset.sum()), 'message')} with a zero "
                         "header.stamp dropped")
            rows, ns = rows[~unset], ns[~unset]
    ns, order = in_time_order(ns, topic, notes)
    return ns, source, notes, rows[order]


def _streams(topic: str, msgtype: str, d: _Decoded,
             clock: tuple[np.ndarray, str, list[str], np.ndarray], origin_ns: int,
             imu: str | None) -> list[Stream]:
    ns, time_source, clock_notes, order = clock
    t = (ns - origin_ns) / 1e9
    device = (d.frame_ids[0] or None) if len(d.frame_ids) == 1 else None  # "" names nothing
    out = []
    for kind, fname, cov, unit in SENSORS[msgtype]:
        values = d.fields[fname][order]
        notes = list(clock_notes)
        if len(d.frame_ids) > 1:
            notes.append(f"{topic}: several header.frame_id values: {', '.join(d.frame_ids)}")
        good = ~np.isnan(values).any(axis=1)
        if not good.all():
            notes.append(f"{topic}: {plural(int((~good).sum()), 'NaN sample')} of "
                         f"{len(values)} dropped ({fname})")
        if cov:
            # sensor_msgs/Imu: element 0 of a covariance at -1 means "this field is not given".
            absent = d.fields[cov][order, 0] == -1.0
            if absent.any():
                notes.append(f"{topic}: {plural(int(absent.sum()), 'message')} mark "
                             f"{fname} absent (covariance[0] = -1); dropped")
                good &= ~absent
        if not good.any():
            continue
        out.append(Stream(
            kind=kind, instance=topic, t=t[good] if not good.all() else t,
            values=np.ascontiguousarray(values[good] if not good.all() else values),
            unit=unit, origin=f"topic {topic} ({msgtype}), field {fname}",
            frame=FRAME if kind != "temp" else None,
            time_source=f"{time_source}, seconds after {_clock_name(origin_ns)}",
            device=device, imu=topic if msgtype == IMU else imu,
            notes=tuple(notes)))
    return out


def _clock_name(origin_ns: int) -> str:
    """The origin of ``t``: a whole second of Unix time for a live recording; a simulation's
    clock (ROS sim time starts near zero) is named as what it is."""
    sec = origin_ns // 1_000_000_000
    return f"{sec} s (Unix time)" if sec >= 946_684_800 else f"{sec} s (not Unix time: " \
        "simulated or since boot)"


def _typestore(conns: list[Any], key: str) -> tuple[Any, list[str]]:
    """The bag's own message definitions (as rosbags' AnyReader builds them); rosbags' stored
    definitions where the bag has none (a ROS 2 bag before Iron)."""
    from rosbags.interfaces import MessageDefinitionFormat as Fmt
    from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore

    types: dict[str, Any] = {}
    notes = []
    for c in conns:
        if c.msgdef.format == Fmt.MSG:
            types.update(get_types_from_msg(c.msgdef.data, c.msgtype))
        elif c.msgdef.format == Fmt.IDL:
            sep = "=" * 80 + "\n"
            if c.msgdef.data.startswith(f"{sep}IDL: "):
                for one in c.msgdef.data.split(sep)[1:]:
                    types.update(get_types_from_idl(one.split("\n", 1)[1]))
            else:
                types.update(get_types_from_idl(c.msgdef.data))
    store = get_typestore(Stores.EMPTY)
    store.register(types)
    if any(c.msgtype not in store.fielddefs for c in conns):
        default = get_typestore(Stores.ROS1_NOETIC if key == "ros1" else Stores.LATEST)
        missing = sorted({c.msgtype for c in conns if c.msgtype not in store.fielddefs})
        store = get_typestore(Stores.EMPTY)
        store.register({**default.fielddefs, **types})
        notes.append(f"no message definition stored for {', '.join(missing)}; "
                     "rosbags' stored definitions used")
    return store, notes


def _hash_soon(path: Path) -> Callable[[], str]:
    """The SHA-256 in a thread while the bag is read (hashlib releases the GIL). A bag
    directory hashes its files in name order."""
    files = sorted(p for p in path.iterdir() if p.is_file()) if path.is_dir() else [path]

    def run() -> str:
        digest = hashlib.sha256()
        for p in files:
            with p.open("rb") as fh:
                while chunk := fh.read(_CHUNK):
                    digest.update(chunk)
        return digest.hexdigest()

    pool = ThreadPoolExecutor(1, thread_name_prefix="imucal-sha256")
    future = pool.submit(run)
    pool.shutdown(wait=False)
    return future.result


def _errors() -> tuple[type[BaseException], ...]:
    """What rosbags and the libraries under it raise on a broken file: their own errors,
    SQLite's, a short read (struct, EOF), a bad decompression (bz2: OSError, lz4:
    RuntimeError, zstd: ZstdError), and a corrupt length that asks for more memory than
    there is."""
    import apsw

    try:
        from backports.zstd import ZstdError
    except ImportError:  # Python 3.14: rosbags uses the standard library's
        from compression.zstd import ZstdError  # type: ignore[import-not-found,no-redef]
    from rosbags.highlevel import AnyReaderError
    from rosbags.rosbag1 import ReaderError as R1
    from rosbags.rosbag2 import ReaderError as R2
    from rosbags.serde import SerdeError
    from rosbags.typesys import TypesysError

    return (R1, R2, AnyReaderError, SerdeError, TypesysError, apsw.Error, _Corrupt,
            struct.error, EOFError, UnicodeDecodeError, OSError, RuntimeError, ZstdError,
            MemoryError)


def read_streams(path: Path, source: str, keep: Callable[[str], bool] | None, key: str,
                 *, fast: bool = True) -> StreamSet:
    """Every IMU, magnetometer and thermometer topic of a ROS 1 bag, ROS 2 bag or MCAP file
    (``key`` from :func:`imucal.io.formats.sniff`) as streams; only the topics ``keep``
    accepts are read. ``fast=False`` decodes every message with rosbags' deserializer."""
    name = FORMAT_NAMES[key]
    broken = _errors()
    if key == "mcap" and path.is_file():
        _check_mcap(path, source)
    if key == "ros2" and path.is_file():
        _check_sqlite(path, source)
    try:
        reader, storages = _open(path, key)
        with _rosbags_internals():
            reader.open()
    except broken as err:
        raise ImucalError(f"cannot open the {name} (corrupt or truncated?): "
                          f"{_one_line(err, path)}", source=source) from None
    digest = _hash_soon(path)
    try:
        conns = list(reader.connections)
        sensors = [c for c in conns if c.msgtype in SENSORS]
        if not sensors:
            raise ImucalError(
                f"the {name} has no {IMU}, {MAG} or {TEMP} topic; it holds "
                f"{_list_topics(conns)}", source=source)
        selected = [c for c in sensors if keep is None or keep(c.topic)]
        topics = {c.topic: _Topic(c.topic, c.msgtype) for c in selected}
        mixed = {c.topic for c in selected if topics[c.topic].msgtype != c.msgtype}
        if mixed:
            raise ImucalError(f"topic {sorted(mixed)[0]} carries two message types; expected "
                              "one", source=source)
        typestore, notes = _typestore(selected, key)
        if selected:  # keep may accept none of them: nothing to read
            _gather(reader, storages, selected, topics)
        decoded = {t: _decode(topic, typestore, key != "ros1", fast)
                   for t, topic in topics.items() if topic.pieces or topic.loose}
    except broken as err:
        raise ImucalError(f"cannot read the {name} (corrupt or truncated?): "
                          f"{_one_line(err, path)}", source=source) from None
    finally:
        reader.close()

    clocks = {t: _clock(t, d) for t, d in decoded.items()}
    origin = min((int(c[0][0]) for c in clocks.values()), default=0)
    origin -= origin % 1_000_000_000  # a whole second: t keeps the stamps' nanoseconds exact
    # A magnetometer or thermometer topic belongs to the Imu topic with its frame_id, when
    # exactly one Imu topic has it (the frame_id is how ROS names the sensor's mount).
    imu_of_frame: dict[str, list[str]] = {}
    for t, d in decoded.items():
        if topics[t].msgtype == IMU and len(d.frame_ids) == 1:
            imu_of_frame.setdefault(d.frame_ids[0], []).append(t)
    streams: list[Stream] = []
    for t, d in decoded.items():
        owner = imu_of_frame.get(d.frame_ids[0], []) if len(d.frame_ids) == 1 else []
        streams.extend(_streams(t, topics[t].msgtype, d, clocks[t], origin,
                                owner[0] if len(owner) == 1 else None))
    empty = [t for t in topics if t not in decoded]
    if empty:
        notes.append(f"{plural(len(empty), 'topic')} without messages: {', '.join(empty)}")
    if streams:
        notes.append(f"times are seconds after {_clock_name(origin)}, the whole second before "
                     "the first sample (float64 seconds since 1970 would lose the stamps' "
                     "nanoseconds)")
        notes.append("axes: FLU (x forward, y left, z up) is what ROS REP 103 states for a body "
                     "frame; a bag does not show that its driver follows it")
    return StreamSet(source=source, format=name, streams=tuple(streams), sha256=digest(),
                     notes=tuple(notes))


def _list_topics(conns: list[Any], most: int = 6) -> str:
    if not conns:
        return "no topics"
    pairs = list(dict.fromkeys(f"{c.topic} ({c.msgtype})" for c in conns))
    more = f" and {len(pairs) - most} more" if len(pairs) > most else ""
    return ", ".join(pairs[:most]) + more


def _one_line(err: BaseException, path: Path) -> str:
    """rosbags' message on one line, without the file's path (the error names it already)
    or the tuple rosbags wraps some messages in."""
    if isinstance(err, MemoryError):
        return "a record's length is larger than memory allows (a corrupt length field)"
    args = err.args
    while len(args) == 1 and isinstance(args[0], tuple):
        args = args[0]
    text = ": ".join(str(a) for a in args) if args else type(err).__name__
    text = text.replace(f"{str(path)!r}", "").replace(str(path), "").replace("(('", "(")
    text = " ".join(text.replace("('", "").replace("',)", "").split())
    return text if len(text) <= 200 else text[:197] + "..."


def _check_sqlite(path: Path, source: str) -> None:
    """A .db3 cut short can still open (SQLite reads what pages it finds): its header states
    the database's size in pages, trusted when the header's two change counters agree."""
    with path.open("rb") as fh:
        head = fh.read(100)
    if len(head) < 100 or path.with_name(path.name + "-wal").exists():
        return  # too short for SQLite to open anyway; with a WAL the header may lag
    page = int.from_bytes(head[16:18], "big")
    page = 65536 if page == 1 else page
    pages = int.from_bytes(head[28:32], "big")
    size = path.stat().st_size
    if head[24:28] == head[92:96] and pages and size < page * pages:
        raise ImucalError(f"the ROS 2 bag is truncated: SQLite's header states {page * pages} "
                          f"bytes, the file holds {size}", source=source)


def _check_mcap(path: Path, source: str) -> None:
    """What rosbags trusts before it reads: an MCAP file ends with the magic it starts with,
    and its header record's length fits in the file (a random length makes rosbags try to
    allocate it)."""
    size = path.stat().st_size
    with path.open("rb") as fh:
        head = fh.read(17)
        fh.seek(max(0, size - 8))
        tail = fh.read(8)
    if len(head) < 17 or tail != b"\x89MCAP0\r\n":
        raise ImucalError("the MCAP file is truncated (it does not end with MCAP's closing "
                          "magic bytes)", source=source)
    if head[8] != 0x01 or int.from_bytes(head[9:17], "little") > size:
        raise ImucalError("the MCAP file is corrupt: its first record is not a header of a "
                          "length that fits in the file", source=source)

