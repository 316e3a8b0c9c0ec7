"""ROS 1 bags, ROS 2 bags and MCAP files (imucal/io/formats/rosbag.py): the shared recordings
against rosbags' own reading, the same recording converted to each format, bags written from
arrays coming back to the bit and the nanosecond, and the refusals."""

from __future__ import annotations

import hashlib
import sqlite3
import sys
from pathlib import Path

import numpy as np
import pytest

from imucal.errors import ImucalError
from imucal.io.formats import read_streams, rosbag, sniff
from imucal.streams import StreamSet

sys.path.insert(0, str(Path(__file__).parent))
from bags import NS, write_bag  # noqa: E402

IMU, MAG = "sensor_msgs/msg/Imu", "sensor_msgs/msg/MagneticField"
SHA256 = {
    "phidgets_imu_upside_down.bag":
        "973274ab33697bcf412f9f6c1b2c1ac798d73afc3eb505374968768a5c85242a",
    "sparkfun_razor.bag": "c2767cb6b3c44adbc665a14721813b9ca125cdd75e5d5863598cbdaeaf252301",
}


def read(path: Path, keep=None, fast: bool = True) -> StreamSet:
    head = path.read_bytes()[:64] if path.is_file() else b""
    key = sniff(head, path)
    assert key in ("ros1", "ros2", "mcap"), path
    if fast:
        return read_streams(path, key, path.name, keep)
    return rosbag.read_streams(path, path.name, keep, key, fast=False)


def origin_ns(ss: StreamSet) -> int:
    """The whole second the times count from, as the StreamSet's note states it."""
    note = next(n for n in ss.notes if n.startswith("times are seconds after "))
    return int(note.split()[4]) * NS


def back_to_ns(ss: StreamSet, t: np.ndarray) -> np.ndarray:
    return np.round(t * 1e9).astype(np.int64) + origin_ns(ss)


def reference(path: Path) -> dict[str, dict[str, np.ndarray | list[str]]]:
    """Each sensor topic read independently: rosbags' AnyReader, message by message."""
    from rosbags.highlevel import AnyReader

    out: dict[str, dict[str, list]] = {}
    with AnyReader([path]) as reader:
        conns = [c for c in reader.connections if c.msgtype in (IMU, MAG)]
        for conn, _, raw in reader.messages(conns):
            msg = reader.deserialize(raw, conn.msgtype)
            d = out.setdefault(conn.topic, {"ns": [], "frame": [], "a": [], "b": []})
            d["ns"].append(msg.header.stamp.sec * NS + msg.header.stamp.nanosec)
            d["frame"].append(msg.header.frame_id)
            if conn.msgtype == IMU:
                a, b = msg.linear_acceleration, msg.angular_velocity
                d["a"].append([a.x, a.y, a.z])
                d["b"].append([b.x, b.y, b.z])
            else:
                m = msg.magnetic_field
                d["a"].append([m.x, m.y, m.z])
    return {topic: {k: (np.array(v) if k != "frame" else v) for k, v in d.items()}
            for topic, d in out.items()}


def assert_same_streams(a: StreamSet, b: StreamSet) -> None:
    assert [s.name for s in a.streams] == [s.name for s in b.streams]
    for x, y in zip(a.streams, b.streams):
        assert np.array_equal(back_to_ns(a, x.t), back_to_ns(b, y.t)), x.name
        assert np.array_equal(x.values, y.values), x.name
        assert (x.unit, x.frame, x.device, x.imu, x.notes) == (y.unit, y.frame, y.device, y.imu,
                                                               y.notes)


# --- the shared recordings ------------------------------------------------------------------

@pytest.fixture(scope="module")
def ros1_dir(shared_data: Path) -> Path:
    return shared_data / "ros1_imu_tools"


@pytest.mark.parametrize("name,rate,counts", [
    ("phidgets_imu_upside_down.bag", 250.0, {"acc": 13964, "gyro": 13964, "mag": 6974}),
    ("sparkfun_razor.bag", 68.95, {"acc": 2144, "gyro": 2144, "mag": 2144}),
])
def test_shared_bags_match_rosbags_own_reading(ros1_dir, name, rate, counts):
    path = ros1_dir / name
    assert hashlib.sha256(path.read_bytes()).hexdigest() == SHA256[name]
    ss = read(path)
    assert ss.sha256 == SHA256[name] and ss.format == "ROS 1 bag"
    assert [s.name for s in ss.streams] == ["acc /imu/data_raw", "gyro /imu/data_raw",
                                            "mag /imu/mag"]
    assert {s.kind: s.samples for s in ss.streams} == counts
    ref = reference(path)
    imu, mag = ref["/imu/data_raw"], ref["/imu/mag"]
    acc, gyro, m = ss.streams
    assert acc.rate == pytest.approx(rate, rel=1e-3) and gyro.rate == acc.rate
    assert (acc.unit, gyro.unit, m.unit) == ("m/s^2", "rad/s", "T")
    assert acc.frame == m.frame == "FLU (ROS REP 103)"
    assert acc.imu == gyro.imu == "/imu/data_raw" and acc.device == imu["frame"][0]
    assert m.device == mag["frame"][0]
    # Every value and stamp, not only the ends (the stamps are in order in these bags).
    assert np.array_equal(acc.values, imu["a"]) and np.array_equal(gyro.values, imu["b"])
    assert np.array_equal(back_to_ns(ss, acc.t), imu["ns"])
    good = ~np.isnan(mag["a"]).any(axis=1)
    assert np.array_equal(m.values, mag["a"][good])
    assert np.array_equal(back_to_ns(ss, m.t), mag["ns"][good])
    if not good.all():
        assert f"{(~good).sum()} NaN samples of {len(good)} dropped" in " ".join(m.notes)


def test_phidgets_figures(ros1_dir):
    """The numbers a user would see, written down once."""
    ss = read(ros1_dir / "phidgets_imu_upside_down.bag")
    acc, gyro, m = ss.streams
    assert acc.t[0] == pytest.approx(0.211312933, abs=1e-12)  # 1360242236.211312933 s
    assert acc.values[0].tolist() == [-0.202086008644104, -0.10555560451507569,
                                      -9.869743322172164]
    assert gyro.values[0].tolist() == [0.0, 0.000351509311351658, 0.004450415059660341]
    assert m.values[0].tolist() == pytest.approx([3.636e-06, 1.4241e-05, 3.4542e-05])
    assert origin_ns(ss) == 1360242236 * NS
    assert acc.duration == pytest.approx(56.239478879, abs=1e-9)
    # Upside down: gravity along -z, about 9.8 m/s^2.
    assert np.mean(acc.values[:, 2]) == pytest.approx(-9.85, abs=0.05)
    assert m.imu == "/imu/data_raw"  # the magnetometer shares the Imu's frame_id "imu"
    assert "6990 NaN samples of 13964 dropped" in m.notes[0]


@pytest.fixture(scope="module")
def converted(ros1_dir, tmp_path_factory) -> dict[str, Path]:
    """The phidgets bag converted by rosbags' converter to a ROS 2 .db3 bag and to MCAP."""
    from rosbags.convert import convert

    root = tmp_path_factory.mktemp("converted")
    src = ros1_dir / "phidgets_imu_upside_down.bag"
    out = {"ros1": src}
    for storage in ("sqlite3", "mcap"):
        dst = root / f"phidgets_{storage}"
        convert([src], dst, storage, 9, None, "file", None, None, [], [], [], [])
        out[storage] = dst
    return out


def test_converted_copies_read_the_same(converted):
    base = read(converted["ros1"])
    db3_dir, mcap_dir = converted["sqlite3"], converted["mcap"]
    for path in (db3_dir, db3_dir / f"{db3_dir.name}.db3", mcap_dir,
                 mcap_dir / f"{mcap_dir.name}.mcap"):
        other = read(path)
        assert other.format == ("MCAP" if path.suffix == ".mcap" else "ROS 2 bag")
        assert_same_streams(base, other)


def test_offsets_agree_with_rosbags_deserializer_on_converted(converted):
    for path in converted.values():
        assert_same_streams(read(path), read(path, fast=False))


# --- bags written from arrays ---------------------------------------------------------------

def signals(n: int, seed: int = 3):
    rng = np.random.default_rng(seed)
    # Unix time with nanosecond jitter: float64 seconds since 1970 could not hold these.
    t = 1_700_000_000 * NS + np.arange(n, dtype=np.int64) * 5_000_000 + rng.integers(0, 999, n)
    acc = rng.normal([0, 0, 9.81], 0.3, (n, 3))
    gyro = rng.normal(0, 0.2, (n, 3))
    mag = rng.normal(0, 5e-5, (n, 3))
    mag[::7] = np.nan  # a driver's "no reading"
    temp = 25 + rng.normal(0, 0.5, n)
    return t, acc, gyro, mag, temp


def targets(path: Path, key: str) -> list[Path]:
    """The file, and for ROS 2 the bag directory around it too."""
    return [path] if key == "ros1" else [path, path.parent]


@pytest.mark.parametrize("key", ["ros1", "ros2", "mcap"])
def test_arrays_come_back_exactly(tmp_path, key):
    n = 700
    t, acc, gyro, mag, temp = signals(n)
    # frame_ids of 1 to 12 characters: every CDR padding after the string, within one topic.
    frames = [("f" * (1 + i % 12)) for i in range(n)]
    path = write_bag(tmp_path / ("b.bag" if key == "ros1" else "b"), key, acc, gyro, t,
                     frame_id=frames, mag=mag, temp=temp)
    for target in targets(path, key):
        for fast in (True, False):
            ss = read(target, fast=fast)
            acc_s, gyro_s, mag_s, temp_s = ss.streams
            assert [s.kind for s in ss.streams] == ["acc", "gyro", "mag", "temp"]
            assert np.array_equal(back_to_ns(ss, acc_s.t), t)  # to the nanosecond
            assert np.array_equal(acc_s.values, acc) and np.array_equal(gyro_s.values, gyro)
            good = ~np.isnan(mag).any(axis=1)
            assert np.array_equal(mag_s.values, mag[good])
            assert np.array_equal(back_to_ns(ss, mag_s.t), t[good])
            assert np.array_equal(temp_s.values[:, 0], temp) and temp_s.unit == "degC"
            assert temp_s.frame is None and mag_s.unit == "T"
            assert acc_s.device is None  # many frame_ids: none names the device
            assert any("several header.frame_id values" in x for x in acc_s.notes)
            assert f"{(~good).sum()} NaN samples of {n} dropped" in " ".join(mag_s.notes)
            assert acc_s.time_source.startswith("header.stamp")


@pytest.mark.parametrize("key", ["ros1", "ros2", "mcap"])
def test_zero_stamps_take_the_receive_time(tmp_path, key):
    t, acc, gyro, *_ = signals(50)
    recv = t + 1_000_000
    path = write_bag(tmp_path / ("b.bag" if key == "ros1" else "b"), key, acc, gyro, t,
                     recv_ns=recv, zero_stamps=True)
    ss = read(path)
    acc_s = ss.streams[0]
    assert np.array_equal(back_to_ns(ss, acc_s.t), recv)
    assert acc_s.time_source.startswith("receive time")
    assert any("every header.stamp is zero" in x for x in acc_s.notes)


def test_messages_before_the_clock_is_set_are_dropped(tmp_path):
    t, acc, gyro, *_ = signals(30)
    stamps = t.copy()
    stamps[:3] = 0  # a driver publishing before its clock is synchronised
    ss = read(write_bag(tmp_path / "b", "mcap", acc, gyro, stamps, recv_ns=t + 50))
    acc_s = ss.streams[0]
    assert np.array_equal(back_to_ns(ss, acc_s.t), t[3:])
    assert np.array_equal(acc_s.values, acc[3:])
    assert "3 messages with a zero header.stamp dropped" in " ".join(acc_s.notes)
    assert acc_s.time_source.startswith("header.stamp")


def test_simulated_clock_is_not_called_unix_time(tmp_path):
    t = np.arange(10, dtype=np.int64) * 10_000_000 + 3 * NS + 7  # sim time: 3 s after start
    acc = gyro = np.zeros((10, 3))
    ss = read(write_bag(tmp_path / "b", "ros2", acc, gyro, t))
    assert origin_ns(ss) == 3 * NS
    assert np.array_equal(back_to_ns(ss, ss.streams[0].t), t)
    assert ss.streams[0].time_source == "header.stamp, seconds after 3 s (not Unix time: " \
        "simulated or since boot)"


@pytest.mark.parametrize("key", ["ros1", "ros2", "mcap"])
def test_unordered_and_repeated_stamps(tmp_path, key):
    t, acc, gyro, *_ = signals(40)
    stamps = t.copy()
    stamps[[10, 11]] = stamps[[11, 10]]  # received in this order: stamps out of order
    stamps[20] = stamps[19]  # a repeated stamp: the second message is dropped
    recv = t + 100_000
    path = write_bag(tmp_path / ("b.bag" if key == "ros1" else "b"), key, acc, gyro, stamps,
                     recv_ns=recv)
    ss = read(path)
    acc_s = ss.streams[0]
    assert np.array_equal(back_to_ns(ss, acc_s.t), np.sort(np.delete(stamps, 20)))
    assert np.array_equal(acc_s.values, acc[np.r_[0:10, 11, 10, 12:20, 21:40]])
    assert np.all(np.diff(acc_s.t) > 0)
    text = " ".join(acc_s.notes)
    assert "not in time order; sorted" in text and "1 repeated stamp dropped" in text


@pytest.mark.parametrize("key", ["ros2", "mcap"])
def test_big_endian_cdr_is_read_by_rosbags(tmp_path, key):
    t, acc, gyro, *_ = signals(30)
    path = write_bag(tmp_path / "b", key, acc, gyro, t, big_endian=True)
    from rosbags.highlevel import AnyReader

    with AnyReader([path.parent]) as reader:
        _, _, raw = next(reader.messages())
        assert bytes(raw[:2]) == b"\x00\x00"  # CDR_BE: the offsets cannot read it
    ss = read(path)
    assert np.array_equal(ss.streams[0].values, acc)
    assert np.array_equal(back_to_ns(ss, ss.streams[1].t), t)


@pytest.mark.parametrize("key,compression", [("ros2", "file"), ("ros2", "message"),
                                             ("mcap", "message"), ("mcap", "storage")])
def test_compressed_ros2_bags(tmp_path, key, compression):
    t, acc, gyro, mag, _ = signals(200)
    path = write_bag(tmp_path / "b", key, acc, gyro, t, mag=mag, compression=compression)
    ss = read(path)
    assert np.array_equal(ss.streams[0].values, acc)
    assert np.array_equal(back_to_ns(ss, ss.streams[1].t), t)
    assert ss.streams[2].samples == np.isfinite(mag).all(axis=1).sum()


def test_mcap_whose_indexes_miss_messages_is_scanned(tmp_path):
    """Where a chunk's message index lacks a channel the statistics count, the file is read
    record by record (rosbags' scan) rather than losing those messages."""
    from rosbags.rosbag2.storage_mcap import McapReader

    t, acc, gyro, *_ = signals(300)
    path = write_bag(tmp_path / "b", "mcap", acc, gyro, t)
    storage = McapReader(path)
    storage.open()
    try:
        conns = list(storage.connections)
        assert storage.chunks and conns[0].msgcount == 300
        storage.chunks[0].message_index_offsets.clear()
        storage.chunks[0].channel_count.clear()
        topic = rosbag._Topic("/imu/data_raw", IMU)
        rosbag._mcap_messages(storage, conns, {"/imu/data_raw": topic})
    finally:
        storage.close()
    store, _ = rosbag._typestore(conns, "mcap")
    decoded = rosbag._decode(topic, store, cdr=True, fast=True)
    assert np.array_equal(decoded.stamp, t) and np.array_equal(
        decoded.fields["linear_acceleration"], acc)


def test_ros1_records_out_of_layout_go_to_rosbags(tmp_path, monkeypatch):
    """Where a record is not laid out as expected, the whole bag is read by rosbags'
    messages() instead, with the same result."""
    t, acc, gyro, mag, _ = signals(500)
    path = write_bag(tmp_path / "b.bag", "ros1", acc, gyro, t, mag=mag)
    fast = read(path)
    calls = []

    def refuse(*args):
        calls.append(1)
        raise rosbag._NotFixed("as if a header differed")

    monkeypatch.setattr(rosbag, "_ros1_records", refuse)
    slow = read(path)
    assert calls and [s.samples for s in slow.streams] == [500, 500, 428]
    assert_same_streams(fast, slow)


def test_db3_with_far_apart_row_ids(tmp_path, monkeypatch):
    """Row ids with gaps (rows deleted, ids given by another writer): every row is read, and
    the windows jump the gaps instead of stepping through them."""
    t, acc, gyro, *_ = signals(300)
    path = write_bag(tmp_path / "b", "ros2", acc, gyro, t)
    with sqlite3.connect(path) as db:
        db.execute("UPDATE messages SET id = id + 1000000000000 WHERE id > 100")
    monkeypatch.setattr(rosbag, "_SQL_WINDOW", 64)
    ss = read(path)
    assert np.array_equal(ss.streams[0].values, acc)
    assert np.array_equal(back_to_ns(ss, ss.streams[0].t), t)


def test_utf16_db3_rows_are_fetched_one_by_one(tmp_path):
    """In a UTF-16 database SQLite would convert the concatenated bytes as text: the rows are
    fetched one by one instead, with the same values."""
    t, acc, gyro, *_ = signals(120)
    src = write_bag(tmp_path / "b", "ros2", acc, gyro, t)
    dst = tmp_path / "utf16.db3"
    with sqlite3.connect(src) as old, sqlite3.connect(dst) as new:
        new.execute("PRAGMA encoding = 'UTF-16le'")
        tables = old.execute("SELECT name, sql FROM sqlite_master WHERE type = 'table'")
        for name, sql in tables.fetchall():
            new.execute(sql)
            rows = old.execute(f"SELECT * FROM {name}").fetchall()
            if rows:
                new.executemany(f"INSERT INTO {name} VALUES ({','.join('?' * len(rows[0]))})",
                                rows)
    with sqlite3.connect(dst) as db:
        assert db.execute("PRAGMA encoding").fetchone()[0] == "UTF-16le"
    ss = read(dst)
    assert np.array_equal(ss.streams[0].values, acc)
    assert np.array_equal(back_to_ns(ss, ss.streams[1].t), t)


def test_keep_leaves_the_other_topics_unread(tmp_path):
    t, acc, gyro, mag, _ = signals(60)
    path = write_bag(tmp_path / "b", "ros2", acc, gyro, t, mag=mag)
    # Break every magnetometer message: one byte each.
    with sqlite3.connect(path) as db:
        db.execute("UPDATE messages SET data = x'00' WHERE topic_id = "
                   "(SELECT id FROM topics WHERE name = '/imu/mag')")
    with pytest.raises(ImucalError, match="cannot read the ROS 2 bag"):
        read(path)
    ss = read(path, keep=lambda topic: topic != "/imu/mag")
    assert [s.name for s in ss.streams] == ["acc /imu/data_raw", "gyro /imu/data_raw"]
    assert np.array_equal(ss.streams[0].values, acc)
    assert read(path, keep=lambda topic: False).streams == ()


def test_a_thermometer_belongs_to_the_imu_of_its_frame(tmp_path):
    t, acc, gyro, *_ = signals(20)
    path = write_bag(tmp_path / "b", "mcap", acc, gyro, t, topic="/imu1/data",
                     temp=np.full(20, 31.5), temp_topic="/imu1/temp", frame_id="imu1_link")
    ss = read(path)
    assert {s.name: (s.imu, s.device) for s in ss.streams} == {
        "acc /imu1/data": ("/imu1/data", "imu1_link"),
        "gyro /imu1/data": ("/imu1/data", "imu1_link"),
        "temp /imu1/temp": ("/imu1/data", "imu1_link")}
    assert np.array_equal(ss.streams[2].values, np.full((20, 1), 31.5))


@pytest.mark.parametrize("key", ["ros1", "ros2"])
def test_acceleration_marked_absent_is_dropped(tmp_path, key):
    """sensor_msgs/Imu: covariance element 0 at -1 says the field is not given."""
    t, acc, gyro, *_ = signals(30)
    cov0 = np.zeros(30)
    cov0[5:9] = -1.0
    path = write_bag(tmp_path / ("b.bag" if key == "ros1" else "b"), key, acc, gyro, t,
                     acc_cov0=cov0)
    ss = read(path)
    acc_s, gyro_s = ss.streams
    assert acc_s.samples == 26 and gyro_s.samples == 30
    assert np.array_equal(acc_s.values, np.delete(acc, np.s_[5:9], axis=0))
    assert "4 messages mark linear_acceleration absent" in " ".join(acc_s.notes)


# --- refusals -------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def small_bags(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("small")
    t, acc, gyro, *_ = signals(300)
    return {key: write_bag(root / ("b.bag" if key == "ros1" else f"b_{key}"), key, acc, gyro, t)
            for key in ("ros1", "ros2", "mcap")}


def one_line_error(path: Path) -> str:
    with pytest.raises(ImucalError) as info:
        read(path)
    text = str(info.value)
    assert "\n" not in text and text.startswith(path.name + ": ")
    return text


@pytest.mark.parametrize("key", ["ros1", "ros2", "mcap"])
def test_no_sensor_topic_lists_what_the_bag_has(tmp_path, key):
    empty = np.zeros((0, 3))
    path = write_bag(tmp_path / ("b.bag" if key == "ros1" else "b"), key, empty, empty,
                     np.zeros(0, np.int64), extra=["/chatter", "/rosout_agg"])
    text = one_line_error(path)
    assert "has no sensor_msgs/msg/Imu, sensor_msgs/msg/MagneticField or " \
           "sensor_msgs/msg/Temperature topic" in text
    assert "/chatter (std_msgs/msg/String), /rosout_agg (std_msgs/msg/String)" in text


@pytest.mark.parametrize("key", ["ros1", "ros2", "mcap"])
@pytest.mark.parametrize("keep", [0.3, 0.9, 0.995])
def test_truncated_file_is_one_line(small_bags, tmp_path, key, keep):
    data = small_bags[key].read_bytes()
    path = tmp_path / f"cut{small_bags[key].suffix}"
    path.write_bytes(data[:int(len(data) * keep)])
    text = one_line_error(path)
    assert "truncated" in text


@pytest.mark.parametrize("key", ["ros1", "ros2", "mcap"])
def test_garbage_after_a_valid_magic_is_one_line(small_bags, tmp_path, key):
    data = small_bags[key].read_bytes()
    path = tmp_path / f"junk{small_bags[key].suffix}"
    magic = {"ros1": 13, "ros2": 16, "mcap": 8}[key]
    path.write_bytes(data[:magic] + np.random.default_rng(5).bytes(20_000))
    one_line_error(path)


@pytest.mark.parametrize("key", ["ros1", "mcap"])
def test_damage_inside_is_one_line(small_bags, tmp_path, key):
    data = bytearray(small_bags[key].read_bytes())
    mid = len(data) // 2
    data[mid:mid + 3000] = np.random.default_rng(6).bytes(3000)
    path = tmp_path / f"hurt{small_bags[key].suffix}"
    path.write_bytes(bytes(data))
    one_line_error(path)


@pytest.mark.parametrize("key", ["ros1", "ros2", "mcap"])
def test_random_damage_is_refused_in_one_line_or_read(small_bags, tmp_path, key):
    """Bytes overwritten, cut or flipped anywhere: the reader either reads the file (the
    formats carry no checksum over message data) or refuses it with an ImucalError; nothing
    else escapes."""
    data = small_bags[key].read_bytes()
    rng = np.random.default_rng(11)
    path = tmp_path / f"fuzz{small_bags[key].suffix}"
    refused = 0
    for trial in range(24):
        b = bytearray(data)
        if trial % 2:
            at = int(rng.integers(0, len(b)))
            b[at:at + 32] = rng.bytes(len(b[at:at + 32]))
        else:
            b = b[:int(rng.integers(1, len(b)))]
        path.write_bytes(bytes(b))
        try:
            read(path)
        except ImucalError as err:
            assert "\n" not in str(err)
            refused += 1
    assert refused >= 12  # every cut file is refused
