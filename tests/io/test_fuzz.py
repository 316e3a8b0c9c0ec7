"""Fuzz the file sniffer and the loaders with mutated real files: whatever the bytes, loading
either succeeds or raises the product's own error (a few thousand cases, seeded)."""

import io
import struct
import zlib
from pathlib import Path

import h5py
import numpy as np
import polars as pl
import scipy.io

import imucal
from imucal.io.load import load_session
from imucal.stages.sanity import gap_warnings, unwrap_session


def _corpus(shared, tmp_path) -> dict[str, bytes]:
    rng = np.random.default_rng(0)
    m = np.column_stack([np.arange(300) / 100.0, rng.normal(0, 0.01, (300, 3)) + [0, 0, 1],
                         rng.normal(0, 0.01, (300, 3))])
    files: dict[str, bytes] = {}
    buf = io.BytesIO()
    scipy.io.savemat(buf, {"acc": m[:, 1:4], "gyro": m[:, 4:], "t": m[:, 0]})
    files["v5.mat"] = buf.getvalue()
    buf = io.BytesIO()
    scipy.io.savemat(buf, {"acc": m[:, 1:4], "gyro": m[:, 4:], "t": m[:, 0]},
                     do_compression=True)
    files["v5z.mat"] = buf.getvalue()
    p = tmp_path / "v73.mat"
    with h5py.File(p, "w") as f:
        f["acc"] = m[:, 1:4].T
        f["gyro"] = m[:, 4:].T
        f["t"] = m[:, :1].T
    files["v73.mat"] = p.read_bytes()
    df = pl.DataFrame({"t": m[:, 0], "ax": m[:, 1], "ay": m[:, 2], "az": m[:, 3],
                       "gx": m[:, 4], "gy": m[:, 5], "gz": m[:, 6]})
    files["s.csv"] = df.write_csv().encode()
    buf = io.BytesIO()
    df.write_parquet(buf)
    files["s.parquet"] = buf.getvalue()
    # Issue 11's silent cases: int16 counts that wrap around, a 5-minute gap in the time.
    counts = np.rint(m[:, 1:] * 16000 + [0, 0, 0, 0, 0, 32000]).astype(np.int64)
    counts[50:200, 5] += np.rint(2500 * np.sin(np.linspace(0, np.pi, 150))).astype(np.int64)
    wrapped = (counts + 32768) % 65536 - 32768  # past 32767 for a while, stored as int16
    files["wrap.csv"] = _csv(np.column_stack([m[:, 0], wrapped]), "%d")
    gap = m.copy()
    gap[150:, 0] += 300.0
    files["gap.csv"] = _csv(gap, "%.6f")
    if shared is not None:
        for rel in ("mikoff_mpu9150/imu0.log", "imu_tk_xsens/xsens_acc.mat",
                    "imucal_ferraris/example_ferraris_session.csv"):
            lines = (shared / rel).read_bytes().splitlines(keepends=True)
            files[rel.replace("/", "_")] = b"".join(lines[:300])
    return files


def _csv(m: np.ndarray, fmt: str) -> bytes:
    buf = io.StringIO()
    np.savetxt(buf, m, delimiter=",", header="t,ax,ay,az,gx,gy,gz", comments="",
               fmt=["%.6f"] + [fmt] * 6)
    return buf.getvalue().encode()


def _mutate(data: bytes, rng: np.random.Generator) -> bytes:
    b = bytearray(data)
    for _ in range(int(rng.integers(1, 6))):
        op = rng.integers(0, 5)
        if not b:
            break
        i = int(rng.integers(0, len(b)))
        if op == 0:
            b[i] = int(rng.integers(0, 256))  # flip a byte
        elif op == 1:
            del b[i:i + int(rng.integers(1, 64))]  # drop a run
        elif op == 2:
            b[i:i] = bytes(rng.integers(0, 256, int(rng.integers(1, 32)), dtype=np.uint8))
        elif op == 3:
            b = b[:i]  # truncate
        else:
            b[i:i] = rng.choice([b",", b"\n", b" ", b"nan", b"-", b"e", b"\t", b"\x00"])
    return bytes(b)


def test_mutated_files_raise_only_imucal_errors(tmp_path):
    shared = Path(__file__).resolve().parents[3] / "shared" / "data"
    files = _corpus(shared if shared.is_dir() else None, tmp_path)
    rng = np.random.default_rng(12345)
    n_ok = n_err = 0
    target = tmp_path / "fuzz.bin"
    for _ in range(2500):
        name = list(files)[int(rng.integers(0, len(files)))]
        target.write_bytes(_mutate(files[name], rng))
        try:
            session = load_session(target, rate=100.0)
            # The input sanity checks (stages/sanity.py) take whatever loads.
            unwrap_session(session)
            gap_warnings(session)
            n_ok += 1
        except imucal.ImucalError as e:
            assert "\n" not in str(e) and "fuzz.bin" in str(e), str(e)
            n_err += 1
    assert n_ok + n_err == 2500 and n_err > 100


def test_mutated_compressed_mat_variables_raise_only_imucal_errors(tmp_path):
    """Mutations inside a compressed MAT v5 variable, compressed again, reach the structural
    check only after inflating: the check, not scipy, must catch them (scipy crashes the
    process on some), and the variables it hands on are the checked ones."""
    m = np.random.default_rng(1).normal(0, 0.01, (300, 3)) + [0, 0, 1]
    buf = io.BytesIO()
    scipy.io.savemat(buf, {"acc": m, "gyro": m - [0, 0, 1], "t": np.arange(300) / 100.0},
                     do_compression=True)
    data = buf.getvalue()
    elements, pos = [], 128
    while pos + 8 <= len(data):
        kind, n = struct.unpack("<II", data[pos:pos + 8])
        elements.append((pos, n))
        pos += 8 + n
    rng = np.random.default_rng(2024)
    target = tmp_path / "fuzz.bin"
    outcomes = {"ok": 0, "error": 0}
    for _ in range(600):
        pos, n = elements[int(rng.integers(0, len(elements)))]
        inner = bytearray(zlib.decompress(data[pos + 8:pos + 8 + n]))
        for _ in range(int(rng.integers(1, 4))):
            i = int(rng.integers(0, len(inner) - 4))
            if rng.random() < 0.5:
                inner[i] = int(rng.integers(0, 256))
            else:  # a tag-sized field: a type code or a size
                inner[i:i + 4] = struct.pack("<I", int(rng.choice(
                    [0, 1, 8, 9, 14, 15, 2**31, 2**32 - 1, int(rng.integers(0, 2**32))])))
        z = zlib.compress(bytes(inner))
        target.write_bytes(data[:pos] + struct.pack("<II", 15, len(z)) + z + data[pos + 8 + n:])
        try:
            load_session(target, rate=100.0)
            outcomes["ok"] += 1
        except imucal.ImucalError as e:
            assert "\n" not in str(e) and "fuzz.bin" in str(e), str(e)
            outcomes["error"] += 1
    assert outcomes["error"] > 100 and outcomes["ok"] > 10, outcomes
