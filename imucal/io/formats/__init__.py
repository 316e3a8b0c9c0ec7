"""Logs of many sensor streams, one module per format, each read with the field's own library:
ROS 1 bags, ROS 2 bags and MCAP (:mod:`.rosbag`, rosbags), PX4 ULog (:mod:`.ulog`, pyulog),
ArduPilot DataFlash and MAVLink telemetry logs (:mod:`.dataflash`, pymavlink), HDF5 and MATLAB
v7.3 files of one dataset per sensor (:mod:`.hdf5`, h5py).

Each module has ``read_streams(path, source, keep) -> StreamSet``: every stream of the file, or
only those whose instance name ``keep`` accepts (the file's other messages are not decoded, so a
large log with one small IMU topic costs what that topic costs). The format is recognised from
the file's first bytes (:func:`sniff`), never from its name alone.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from pathlib import Path

from imucal.streams import StreamSet

Keep = Callable[[str], bool] | None

# format key -> (the module that reads it, the name shown to a user)
FORMATS = {
    "ros1": ("rosbag", "ROS 1 bag"),
    "ros2": ("rosbag", "ROS 2 bag"),
    "mcap": ("rosbag", "MCAP"),
    "ulog": ("ulog", "PX4 ULog"),
    "dataflash": ("dataflash", "ArduPilot DataFlash log"),
    "tlog": ("dataflash", "MAVLink telemetry log"),
    "hdf5": ("hdf5", "HDF5"),
}

_MAGIC = (
    (b"#ROSBAG V2.0", "ros1"),
    (b"\x89MCAP0\r\n", "mcap"),
    (b"SQLite format 3\x00", "ros2"),
    (b"ULog\x01\x12\x35", "ulog"),
)
# A tlog is MAVLink frames each after an 8-byte big-endian time in microseconds since 1970:
# the first frame's start byte (0xFE MAVLink 1, 0xFD MAVLink 2) sits at offset 8.
_HDF5 = b"\x89HDF\r\n\x1a\n"  # at 0, or at 512 after a MATLAB v7.3 file's text header
_TLOG_US = (946_684_800 * 10**6, 4_102_444_800 * 10**6)  # years 2000 to 2100


def sniff(head: bytes, path: Path | None = None) -> str | None:
    """The format key of a file whose first bytes (1024 of them) are ``head``, or None when it
    is none of these (a table, a .mat, ...). A directory holding ``metadata.yaml`` is a ROS 2
    bag. An HDF5 file (with ``path``) is one only when its datasets name sensors in a layout
    the table loader does not read (:func:`.hdf5.is_stream_file`)."""
    if path is not None and path.is_dir():
        return "ros2" if (path / "metadata.yaml").is_file() else None
    for magic, key in _MAGIC:
        if head.startswith(magic):
            return key
    if len(head) >= 3 and head[0] == 0xA3 and head[1] == 0x95:
        return "dataflash"  # DataFlash's two header bytes, then a message id (FMT: 0x80)
    if len(head) > 8 and head[8] in (0xFE, 0xFD):
        if _TLOG_US[0] <= int.from_bytes(head[:8], "big") <= _TLOG_US[1]:
            return "tlog"
    if path is not None and (head[:8] == _HDF5 or head[512:520] == _HDF5):
        from imucal.io.formats.hdf5 import is_stream_file

        try:
            return "hdf5" if is_stream_file(path) else None
        except Exception:  # noqa: BLE001 - the table loader's reader says what is wrong
            return None
    return None


def read_streams(path: Path, key: str, source: str, keep: Keep = None) -> StreamSet:
    """Read a file of format ``key`` (from :func:`sniff`) with its format's module."""
    module = importlib.import_module(f"{__name__}.{FORMATS[key][0]}")
    return module.read_streams(path, source, keep, key)
