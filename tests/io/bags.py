"""Bags written from arrays with rosbags' own writers and serializers (ROS 1 ``.bag``, ROS 2
``.db3``, MCAP): the reader under test never writes what it reads back.

``write_bag(path, key, acc, gyro, t)`` writes one ``sensor_msgs/msg/Imu`` topic (and optionally
a MagneticField and a Temperature topic on the same stamps) and returns the file to read:
the ``.bag`` itself, or the ``.db3`` / ``.mcap`` file inside the ROS 2 bag directory ``path``
(its parent is the bag directory, with ``metadata.yaml``).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

NS = 1_000_000_000


def stamps_ns(t: np.ndarray) -> np.ndarray:
    """Times as integer nanoseconds: integer arrays are taken as nanoseconds already, floats
    as seconds (rounded to the nanosecond)."""
    t = np.asarray(t)
    return t.astype(np.int64) if t.dtype.kind in "iu" else np.round(t * NS).astype(np.int64)


def write_bag(path: Path, key: str, acc: np.ndarray, gyro: np.ndarray, t: np.ndarray, *,
              topic: str = "/imu/data_raw", frame_id: str | Sequence[str] = "imu",
              mag: np.ndarray | None = None, mag_topic: str = "/imu/mag",
              temp: np.ndarray | None = None, temp_topic: str = "/imu/temperature",
              recv_delay_ns: int = 250_000, zero_stamps: bool = False,
              recv_ns: np.ndarray | None = None, big_endian: bool = False,
              acc_cov0: np.ndarray | None = None, extra: Sequence[str] = (),
              extra_bytes: int = 12, extra_every: int = 0, compression: str | None = None,
              ) -> Path:
    """Write a bag of format ``key`` ("ros1", "ros2" for .db3, "mcap") at ``path``.

    ``acc``, ``gyro`` (and ``mag``) are (N, 3) in m/s^2, rad/s and tesla, ``temp`` (N,) in
    degC, ``t`` the header stamps (seconds, or integer nanoseconds). Each message is recorded
    ``recv_delay_ns`` after its stamp (the receive time), or at ``recv_ns`` (integer
    nanoseconds, one per sample); messages are written in receive order. ``zero_stamps``
    writes zero header stamps, as some drivers do. ``frame_id`` may be one per message;
    ``big_endian`` writes ROS 2 messages in big-endian CDR (rare, but legal). ``acc_cov0``
    sets element 0 of each message's linear_acceleration_covariance (-1: "no acceleration").
    ``extra`` names std_msgs/msg/String topics (a bag with other topics): one message each
    of ``extra_bytes`` characters, or one every ``extra_every`` IMU messages (a large other
    topic beside a small IMU topic). ``compression`` (ROS 2: "file", "message", or "storage"
    for MCAP's zstd chunks) compresses with zstd; a "file" or "message" bag is returned as its
    directory, which is then the only way to read it.
    """
    from rosbags.typesys import Stores, get_typestore

    ns = stamps_ns(t)
    recv = ns + recv_delay_ns if recv_ns is None else np.asarray(recv_ns, np.int64)
    ros1 = key == "ros1"
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    T = store.types
    frames = [frame_id] * len(ns) if isinstance(frame_id, str) else list(frame_id)

    def serialize(msg: object, msgtype: str) -> bytes:
        if ros1:
            return bytes(store.serialize_ros1(msg, msgtype))
        return bytes(store.serialize_cdr(msg, msgtype, little_endian=not big_endian))

    def header(i: int, n: int) -> object:
        stamp = T["builtin_interfaces/msg/Time"](sec=0 if zero_stamps else int(n // NS),
                                                   nanosec=0 if zero_stamps else int(n % NS))
        if ros1:
            return T["std_msgs/msg/Header"](seq=i, stamp=stamp, frame_id=frames[i])
        return T["std_msgs/msg/Header"](stamp=stamp, frame_id=frames[i])

    def vec(v: np.ndarray) -> object:
        return T["geometry_msgs/msg/Vector3"](x=float(v[0]), y=float(v[1]), z=float(v[2]))

    cov = np.zeros(9)
    msgs: list[tuple[str, str, int, object]] = []
    for i, (n, r) in enumerate(zip(ns.tolist(), recv.tolist())):
        msgs.append((topic, "sensor_msgs/msg/Imu", r, T["sensor_msgs/msg/Imu"](
            header=header(i, n),
            orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=np.array([-1.0, 0, 0, 0, 0, 0, 0, 0, 0]),
            angular_velocity=vec(gyro[i]), angular_velocity_covariance=cov,
            linear_acceleration=vec(acc[i]),
            linear_acceleration_covariance=cov if acc_cov0 is None
            else np.r_[acc_cov0[i], cov[1:]])))
        if mag is not None:
            msgs.append((mag_topic, "sensor_msgs/msg/MagneticField", r,
                         T["sensor_msgs/msg/MagneticField"](
                             header=header(i, n), magnetic_field=vec(mag[i]),
                             magnetic_field_covariance=cov)))
        if temp is not None:
            msgs.append((temp_topic, "sensor_msgs/msg/Temperature", r,
                         T["sensor_msgs/msg/Temperature"](
                             header=header(i, n), temperature=float(temp[i]), variance=0.0)))
    at = recv[::extra_every] if extra_every and len(recv) else recv[:1] if len(recv) else [0]
    filler = T["std_msgs/msg/String"](data="x" * extra_bytes)
    for name in extra:
        msgs.extend((name, "std_msgs/msg/String", int(r), filler) for r in at)
    # Recorded in receive order, as a recorder writes them (a stable sort: ties keep order).
    msgs.sort(key=lambda m: m[2])
    topics = dict.fromkeys((m[0], m[1]) for m in msgs)

    if ros1:
        from rosbags.rosbag1 import Writer as Writer1

        with Writer1(path) as writer:
            conns = {(tp, mt): writer.add_connection(tp, mt, typestore=store) for tp, mt in topics}
            for tp, mt, n, msg in msgs:
                writer.write(conns[tp, mt], n, serialize(msg, mt))
        return path

    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2

    plugin = StoragePlugin.MCAP if key == "mcap" else StoragePlugin.SQLITE3
    bag = Writer2(path, version=9, storage_plugin=plugin)
    if compression:
        from rosbags.rosbag2 import CompressionFormat, CompressionMode

        bag.set_compression(CompressionMode[compression.upper()], CompressionFormat.ZSTD)
    with bag as writer:
        conns = {(tp, mt): writer.add_connection(tp, mt, typestore=store) for tp, mt in topics}
        for tp, mt, n, msg in msgs:
            writer.write(conns[tp, mt], n, serialize(msg, mt))
    if compression in ("file", "message"):
        return path
    return path / f"{path.name}.{'mcap' if key == 'mcap' else 'db3'}"
