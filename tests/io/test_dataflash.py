"""ArduPilot DataFlash and MAVLink telemetry logs (imucal.io.formats.dataflash): the shared
DataFlash log checked against pymavlink's own message-by-message reading (``recv_match``), a
telemetry log written here with pymavlink's encoder read back exactly, and the refusals."""

from __future__ import annotations

import hashlib
import struct
from pathlib import Path

import numpy as np
import pytest

from imucal.errors import ImucalError
from imucal.io.formats import dataflash as df_reader
from imucal.io.formats import read_streams, sniff

SHA256 = "a51f040b2ad7f55185c1da5705f226f51469b86562c4ff76d05c99e0e52c2bf4"
NAMES = ["acc IMU", "gyro IMU", "temp IMU", "acc IMU2", "gyro IMU2", "temp IMU2", "mag MAG",
         "mag MAG2", "mag MAG3"]


@pytest.fixture(scope="module")
def bin_path(shared_data: Path) -> Path:
    return shared_data / "ardupilot_dataflash" / "test.BIN"


@pytest.fixture(scope="module")
def streams(bin_path: Path):
    return read_streams(bin_path, sniff(bin_path.read_bytes()[:16], bin_path), "test.BIN")


def _reference(path: Path) -> dict[str, list[dict]]:
    """pymavlink's own reading, message by message: the independent truth here."""
    from pymavlink import mavutil

    log = mavutil.mavlink_connection(str(path))
    out: dict[str, list[dict]] = {}
    try:
        while (m := log.recv_match(type=["IMU", "IMU2", "MAG", "MAG2", "MAG3"])) is not None:
            out.setdefault(m.get_type(), []).append(m.to_dict())
    finally:
        log.close()  # left to the garbage collector, it warned inside whichever test ran then
    return out


def test_shared_log_streams_named_counted_and_hashed(bin_path, streams):
    ref = _reference(bin_path)
    assert hashlib.sha256(bin_path.read_bytes()).hexdigest() == SHA256 == streams.sha256
    assert streams.format == "ArduPilot DataFlash log"
    assert [s.name for s in streams.streams] == NAMES
    s = {x.name: x for x in streams.streams}
    for name in ("IMU", "IMU2"):
        assert s[f"acc {name}"].samples == len(ref[name]) == 45
        assert s[f"acc {name}"].imu == s[f"gyro {name}"].imu == s[f"temp {name}"].imu == name
        assert s[f"acc {name}"].rate == pytest.approx(50.0, rel=0.01)
    for name in ("MAG", "MAG2", "MAG3"):
        assert s[f"mag {name}"].samples == len(ref[name]) == 8
        assert s[f"mag {name}"].rate == pytest.approx(10.0, rel=0.01)
        assert s[f"mag {name}"].unit == "mG"
    assert {x.unit for x in streams.of_kind("acc")} == {"m/s^2"}
    assert {x.unit for x in streams.of_kind("gyro")} == {"rad/s"}
    assert s["acc IMU"].frame == "FRD (ArduPilot body frame: AHRS_ORIENTATION applied)"
    assert s["acc IMU"].time_source.startswith("TimeUS")
    # the shared file is the first 64 KiB of a longer log: it ends inside a message
    assert streams.notes == ("truncated: the file ends inside its last message (AHR2, at byte "
                             "65512); read up to there",)


def test_values_and_times_are_pymavlinks(bin_path, streams):
    ref = _reference(bin_path)
    s = {x.name: x for x in streams.streams}
    for name in ("IMU", "IMU2"):
        rows = ref[name]
        np.testing.assert_array_equal(s[f"acc {name}"].t, [r["TimeUS"] / 1e6 for r in rows])
        np.testing.assert_array_equal(s[f"acc {name}"].values,
                                      [[r["AccX"], r["AccY"], r["AccZ"]] for r in rows])
        np.testing.assert_array_equal(s[f"gyro {name}"].values,
                                      [[r["GyrX"], r["GyrY"], r["GyrZ"]] for r in rows])
        np.testing.assert_array_equal(s[f"temp {name}"].values[:, 0], [r["T"] for r in rows])
    np.testing.assert_array_equal(s["mag MAG3"].values,
                                  [[r["MagX"], r["MagY"], r["MagZ"]] for r in ref["MAG3"]])
    assert s["acc IMU"].values[0] == pytest.approx([0.41619188, 0.46917608, -9.78099442])
    assert s["temp IMU"].values[0, 0] == pytest.approx(44.42328, abs=1e-5)
    assert s["temp IMU2"].values[-1, 0] == pytest.approx(39.95039, abs=1e-5)
    assert s["mag MAG"].values[0].tolist() == [219.0, 179.0, -517.0]
    assert s["mag MAG"].t[-1] == 82.690217


def test_keep_skips_message_types(bin_path):
    got = df_reader.read_streams(bin_path, "test.BIN", lambda inst: inst == "IMU2", "dataflash")
    assert [s.name for s in got.streams] == ["acc IMU2", "gyro IMU2", "temp IMU2"]


def test_cut_log_reads_what_pymavlink_reads(bin_path, tmp_path):
    cut = tmp_path / "cut.bin"
    cut.write_bytes(bin_path.read_bytes()[:40_001])
    got = df_reader.read_streams(cut, "cut.bin", None, "dataflash")
    ref = _reference(cut)
    s = {x.name: x for x in got.streams}
    assert s["acc IMU"].samples == len(ref["IMU"]) == 7
    assert s["acc IMU2"].samples == len(ref["IMU2"]) == 6
    assert got.notes == ("truncated: the file ends inside its last message (IMU2, at byte "
                         "39995); read up to there",)


def test_corrupt_stretch_is_a_note_not_a_flood(bin_path, tmp_path, capfd):
    data = bin_path.read_bytes()
    bad = tmp_path / "zeros.bin"
    bad.write_bytes(data[:30_000] + b"\0" * 2000 + data[32_000:])
    got = df_reader.read_streams(bad, "zeros.bin", None, "dataflash")
    out, err = capfd.readouterr()
    assert out == err == ""  # pymavlink's indexer prints one line per skipped byte
    assert got.notes[0] == ("corrupt stretches: pymavlink skipped 2005 bytes that start no "
                            "valid message")
    assert {x.name: x.samples for x in got.streams}["acc IMU"] == 44


def test_garbage_after_the_magic_is_one_line(tmp_path):
    rng = np.random.default_rng(0)
    path = tmp_path / "garbage.bin"
    path.write_bytes(b"\xa3\x95\x80" + rng.integers(0, 256, 5000, dtype=np.uint8).tobytes())
    assert sniff(path.read_bytes()[:16], path) == "dataflash"
    with pytest.raises(ImucalError) as err:
        read_streams(path, "dataflash", "garbage.bin")
    text = str(err.value)
    assert text.startswith("garbage.bin: cannot read the ArduPilot DataFlash log: ")
    assert "\n" not in text and len(text) < 300


def test_log_without_imu_messages_is_refused(bin_path, tmp_path):
    path = tmp_path / "formats_only.bin"
    path.write_bytes(bin_path.read_bytes()[:1000])  # the FMT messages that open the log
    with pytest.raises(ImucalError) as err:
        read_streams(path, "dataflash", "formats_only.bin")
    assert str(err.value) == (
        "formats_only.bin: no IMU or compass message (IMU, IMU2, IMU3, ACC, ACC1, ACC2, ACC3, "
        "GYR, GYR1, GYR2, GYR3, MAG, MAG2, MAG3) in the ArduPilot DataFlash log; it has 1 "
        "message type: FMT")


# --- MAVLink telemetry logs -------------------------------------------------------------------


def _write_tlog(path: Path, n: int = 40, version: int = 2) -> dict:
    """A tlog as a ground station writes one: each frame after its 8-byte big-endian receive
    time in µs. SCALED_IMU and SCALED_IMU2 at 50 Hz, HIGHRES_IMU at 100 Hz."""
    if version == 2:
        from pymavlink.dialects.v20 import common as dialect
    else:
        from pymavlink.dialects.v10 import common as dialect
    mav = dialect.MAVLink(None, srcSystem=1, srcComponent=1)
    i = np.arange(n)
    scaled = np.column_stack([1000 + 20 * i, 12 + i % 5, -5 - i % 3, 1001 - i % 7, 3 * i % 11,
                              2 - i % 4, -7 + i % 2, 210 + i % 3, 180 + 0 * i, -520 + i % 9,
                              2550 + i])
    high = np.column_stack([5_000_000 + 10_000 * i, 0.1 * i, 0.2 - 0.01 * i, -9.81 + 0.001 * i,
                            0.01 * i, -0.02 + 0 * i, 0.003 + 0 * i, 0.21 + 0 * i, 0.18 + 0 * i,
                            -0.52 + 0.001 * i, 25.5 + 0.01 * i])
    with path.open("wb") as f:
        for k in range(n):
            t_us = 1_700_000_000_000_000 + 20_000 * k
            row = [int(v) for v in scaled[k]]
            row2 = [row[0], *[v + 1 for v in row[1:10]], row[10]]
            ext = 11 if version == 2 else 10  # MAVLink 1 has no extension fields
            for m in (mav.scaled_imu_encode(*row[:ext]), mav.scaled_imu2_encode(*row2[:ext])):
                f.write(struct.pack(">Q", t_us) + m.pack(mav))
            for h in (2 * k, 2 * k + 1):
                v = high[h % n].tolist()
                args = [int(5_000_000 + 10_000 * h), *v[1:10], 1013.0, 0.0, 100.0, v[10],
                        0x1FFF, 0]
                m = mav.highres_imu_encode(*args[:16 if version == 2 else 15])
                f.write(struct.pack(">Q", t_us + 5) + m.pack(mav))
    return {"scaled": scaled, "high": high}


def test_tlog_read_back_exactly(tmp_path):
    path = tmp_path / "flight.tlog"
    truth = _write_tlog(path)
    assert sniff(path.read_bytes()[:16], path) == "tlog"
    got = read_streams(path, "tlog", "flight.tlog")
    assert got.format == "MAVLink telemetry log"
    assert [s.name for s in got.streams] == [
        "acc SCALED_IMU", "gyro SCALED_IMU", "mag SCALED_IMU", "temp SCALED_IMU",
        "acc SCALED_IMU2", "gyro SCALED_IMU2", "mag SCALED_IMU2", "temp SCALED_IMU2",
        "acc HIGHRES_IMU", "gyro HIGHRES_IMU", "mag HIGHRES_IMU", "temp HIGHRES_IMU"]
    s = {x.name: x for x in got.streams}
    sc = truth["scaled"]
    # mg -> g, mrad/s -> rad/s and cdegC -> degC by one division each; mgauss kept
    np.testing.assert_array_equal(s["acc SCALED_IMU"].t, sc[:, 0] / 1000)
    np.testing.assert_array_equal(s["acc SCALED_IMU"].values, sc[:, 1:4] / 1000)
    np.testing.assert_array_equal(s["gyro SCALED_IMU"].values, sc[:, 4:7] / 1000)
    np.testing.assert_array_equal(s["mag SCALED_IMU"].values, sc[:, 7:10])
    np.testing.assert_array_equal(s["temp SCALED_IMU"].values[:, 0], sc[:, 10] / 100)
    np.testing.assert_array_equal(s["acc SCALED_IMU2"].values, (sc[:, 1:4] + 1) / 1000)
    assert (s["acc SCALED_IMU"].unit, s["gyro SCALED_IMU"].unit, s["mag SCALED_IMU"].unit) == \
        ("g", "rad/s", "mG")
    assert s["acc SCALED_IMU"].imu == "SCALED_IMU" and s["mag SCALED_IMU"].imu is None
    assert s["acc SCALED_IMU"].rate == pytest.approx(50.0)
    # HIGHRES_IMU: float32 on the wire, SI units
    hi = truth["high"]
    h = np.arange(2 * len(hi)) % len(hi)
    np.testing.assert_array_equal(s["acc HIGHRES_IMU"].t, (5_000_000 + 10_000 * np.arange(
        2 * len(hi))) / 1e6)
    np.testing.assert_array_equal(s["acc HIGHRES_IMU"].values,
                                  hi[h, 1:4].astype(np.float32).astype(np.float64))
    np.testing.assert_array_equal(s["gyro HIGHRES_IMU"].values,
                                  hi[h, 4:7].astype(np.float32).astype(np.float64))
    np.testing.assert_array_equal(s["temp HIGHRES_IMU"].values[:, 0],
                                  hi[h, 10].astype(np.float32).astype(np.float64))
    assert (s["acc HIGHRES_IMU"].unit, s["mag HIGHRES_IMU"].unit) == ("m/s^2", "gauss")
    assert s["acc HIGHRES_IMU"].rate == pytest.approx(100.0)
    assert got.notes == ()


def test_tlog_mavlink1_has_no_thermometer(tmp_path):
    """MAVLink 1 frames drop the extension fields (SCALED_IMU's temperature): 0 on reading,
    which MAVLink defines as "no thermometer": no temp stream, not a stream of zeros."""
    path = tmp_path / "v1.tlog"
    truth = _write_tlog(path, n=10, version=1)
    got = read_streams(path, "tlog", "v1.tlog")
    names = [s.name for s in got.streams]
    assert "temp SCALED_IMU" not in names and "acc SCALED_IMU" in names
    s = {x.name: x for x in got.streams}
    np.testing.assert_array_equal(s["acc SCALED_IMU"].values, truth["scaled"][:, 1:4] / 1000)


def test_tlog_keep_and_garbage(tmp_path):
    path = tmp_path / "flight.tlog"
    _write_tlog(path, n=10)
    got = read_streams(path, "tlog", "flight.tlog", keep=lambda inst: inst == "SCALED_IMU2")
    assert {s.instance for s in got.streams} == {"SCALED_IMU2"}
    # random bytes after the frames: skipped by pymavlink, said in a note
    rng = np.random.default_rng(1)
    path.write_bytes(path.read_bytes() + rng.integers(0, 256, 3000, dtype=np.uint8).tobytes())
    got = read_streams(path, "tlog", "flight.tlog")
    assert {x.name: x.samples for x in got.streams}["acc SCALED_IMU"] == 10
    assert "corrupt stretches: pymavlink found bytes that form no valid MAVLink message " \
           "(skipped)" in got.notes


# --- newer DataFlash layouts: one message type, an instance field I ----------------------------

_FORMATS = {  # id: (name, struct format, DataFlash format, columns), as ArduPilot 4.x logs them
    # T as "c": int16 centidegrees, which DataFlash's format char scales by 0.01
    200: ("IMU", "<QBffffffIIhBBHH", "QBffffffIIcBBHH",
          "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz"),
    201: ("ACC", "<QBQfff", "QBQfff", "TimeUS,I,SampleUS,AccX,AccY,AccZ"),
    202: ("GYR", "<QBQfff", "QBQfff", "TimeUS,I,SampleUS,GyrX,GyrY,GyrZ"),
    203: ("MAG", "<QBhhhhhhhhhBI", "QBhhhhhhhhhBI",
          "TimeUS,I,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOfsX,MOfsY,MOfsZ,Health,S"),
}


# ArduPilot's unit and multiplier tables (UNIT, MULT) and each format's units (FMTU): what
# pymavlink reads a column's unit from in newer logs.
_META = {210: ("UNIT", "<QbZ", "QbZ", "TimeUS,Id,Label"),
         211: ("MULT", "<Qbd", "Qbd", "TimeUS,Id,Mult"),
         212: ("FMTU", "<QBNN", "QBNN", "TimeUS,FmtType,UnitIds,MultIds")}
_UNIT_IDS = {200: ("s#EEEooo--O----", "F-------------"),
             201: ("s#sooo", "F-F---"), 202: ("s#sEEE", "F-F---"),
             203: ("s#GGGGGGGGG-s", "F-CCCCCCCCC-F")}


def _write_instanced_bin(path: Path, n: int = 20, mag_unit: str = "G") -> None:
    out = bytearray()
    for mid, (name, st, fmt, cols) in {**_FORMATS, **_META}.items():
        st = st.replace("Z", "64s").replace("N", "16s")
        out += b"\xa3\x95\x80" + struct.pack("<BB4s16s64s", mid, 3 + struct.calcsize(st),
                                             name.encode(), fmt.encode(), cols.encode())
    for uid, label in (("s", "s"), ("#", "instance"), ("E", "rad/s"), ("o", "m/s/s"),
                       ("O", "degC"), ("G", "Gauss"), ("-", "")):
        out += b"\xa3\x95" + bytes([210]) + struct.pack("<Qb64s", 0, ord(uid), label.encode())
    for mid_, mult in (("-", 0.0), ("F", 1e-6), ("C", 1e-3)):
        out += b"\xa3\x95" + bytes([211]) + struct.pack("<Qbd", 0, ord(mid_), mult)
    for mid, (units, mults) in _UNIT_IDS.items():
        units = units.replace("G", mag_unit, 1) if mid == 203 else units
        out += b"\xa3\x95" + bytes([212]) + struct.pack("<QB16s16s", 0, mid, units.encode(),
                                                         mults.encode())
    for k in range(n):
        t = 1_000_000 + 2500 * k
        for i in (0, 1):
            g = (0.01 * k, -0.02 * i, 0.003)
            a = (0.1 * i, 0.2, -9.8 + 0.001 * k)
            out += b"\xa3\x95" + bytes([200]) + struct.pack(
                "<QBffffffIIhBBHH", t, i, *g, *a, 0, 0, 3000 + 100 * i + k, 1, 1, 1000, 1000)
            for j in (1, 0):  # two raw samples per instance per step, sampled 1250 µs apart
                out += b"\xa3\x95" + bytes([201]) + struct.pack(
                    "<QBQfff", t + 7, i, t - 1250 * j, 0.5 * i, 0.25 * j, -9.75)
                out += b"\xa3\x95" + bytes([202]) + struct.pack(
                    "<QBQfff", t + 9, i, t - 1250 * j, 0.125 * j, 0.5 * i, 0.0)
            if k % 4 == 0:
                out += b"\xa3\x95" + bytes([203]) + struct.pack(
                    "<QBhhhhhhhhhBI", t + 11, i, 200 + k, -100 * i, -500, 0, 0, 0, 0, 0, 0, 1,
                    t)
    path.write_bytes(bytes(out))


def test_instance_field_splits_one_message_type(tmp_path):
    path = tmp_path / "new.bin"
    _write_instanced_bin(path)
    got = read_streams(path, "dataflash", "new.bin")
    s = {x.name: x for x in got.streams}
    assert list(s) == ["acc IMU[0]", "gyro IMU[0]", "temp IMU[0]", "acc IMU[1]", "gyro IMU[1]",
                       "temp IMU[1]", "acc ACC[0]", "acc ACC[1]", "gyro GYR[0]", "gyro GYR[1]",
                       "mag MAG[0]", "mag MAG[1]"]
    k = np.arange(20)
    np.testing.assert_array_equal(s["acc IMU[1]"].t, (1_000_000 + 2500 * k) / 1e6)
    np.testing.assert_array_equal(s["acc IMU[1]"].values[:, 2],
                                  np.float32(-9.8 + 0.001 * k).astype(np.float64))
    np.testing.assert_array_equal(s["temp IMU[1]"].values[:, 0], (3100 + k) / 100)
    assert s["acc IMU[0]"].imu == s["gyro IMU[0]"].imu == "IMU[0]"
    # ACC and GYR: every sample, on SampleUS (when sampled), 800 Hz here
    acc = s["acc ACC[1]"]
    assert acc.samples == 40 and acc.time_source.startswith("SampleUS")
    assert acc.rate == pytest.approx(800.0)
    assert acc.t[0] == (1_000_000 - 1250) / 1e6
    np.testing.assert_array_equal(acc.values[:2], [[0.5, 0.25, -9.75], [0.5, 0.0, -9.75]])
    assert acc.imu == s["gyro GYR[1]"].imu == "ACC[1]+GYR[1]"
    assert s["mag MAG[1]"].values[0].tolist() == [200.0, -100.0, -500.0]
    assert s["mag MAG[0]"].samples == 5
    only = read_streams(path, "dataflash", "new.bin", keep=lambda inst: inst == "GYR[0]")
    assert [x.name for x in only.streams] == ["gyro GYR[0]"]
    assert got.notes == ()  # the log's units (FMTU) are the ones assumed
    _same_both_ways(path)


def test_a_unit_the_log_states_otherwise_is_said(tmp_path):
    path = tmp_path / "odd_unit.bin"
    _write_instanced_bin(path, mag_unit="o")  # MagX in m/s/s: a log that contradicts itself
    got = read_streams(path, "dataflash", "odd_unit.bin")
    assert got.notes == ("MAG: the log states MagX in 'mm/s/s'; read as 'mGauss' (ArduPilot's "
                         "unit for it)",)


def _same_both_ways(path: Path) -> None:
    """The records decoded from pymavlink's index equal pymavlink's own decoding, message by
    message (``recv_match``)."""
    fast = df_reader.read_streams(path, path.name, None, "dataflash")
    slow = df_reader.read_streams(path, path.name, None, "dataflash", fast=False)
    assert [s.name for s in fast.streams] == [s.name for s in slow.streams]
    assert fast.notes == slow.notes
    for a, b in zip(fast.streams, slow.streams):
        np.testing.assert_array_equal(a.t, b.t)
        np.testing.assert_array_equal(a.values, b.values)


def test_indexed_decoding_equals_pymavlinks(bin_path, tmp_path):
    _same_both_ways(bin_path)
    data = bin_path.read_bytes()
    for name, cut in (("cut.bin", data[:40_001]),
                      ("zeros.bin", data[:30_000] + b"\0" * 2000 + data[32_000:])):
        (tmp_path / name).write_bytes(cut)
        _same_both_ways(tmp_path / name)


def test_tlog_two_senders_of_one_message_are_two_streams(tmp_path):
    from pymavlink.dialects.v20 import common as dialect

    path = tmp_path / "two.tlog"
    with path.open("wb") as f:
        for k in range(10):
            for sysid in (1, 2):
                mav = dialect.MAVLink(None, srcSystem=sysid, srcComponent=1)
                m = mav.highres_imu_encode(10_000 * k, 0.0, 0.0, -9.81 * sysid, 0.0, 0.0, 0.0,
                                           0.2, 0.0, 0.4, 1013.0, 0.0, 0.0, 20.0, 0x1FFF, 0)
                f.write(struct.pack(">Q", 1_700_000_000_000_000 + 10_000 * k + sysid)
                        + m.pack(mav))
    got = read_streams(path, "tlog", "two.tlog")
    acc = {x.instance: x for x in got.of_kind("acc")}
    assert sorted(acc) == ["HIGHRES_IMU@1/1", "HIGHRES_IMU@2/1"]
    assert acc["HIGHRES_IMU@2/1"].values[0, 2] == np.float64(np.float32(-19.62))
    assert acc["HIGHRES_IMU@1/1"].samples == 10
