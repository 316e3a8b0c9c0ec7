"""How fast a PX4 ULog's sensor streams are read (imucal.io.formats.ulog), against pyulog alone
and against loading the same samples from .npy files, in one process on one core.

    PYTHONPATH=$PWD python bench/read_speed_ulog.py [--seconds 200] [--out bench/read_speed_ulog.md]

Two files: the shared flight log (../shared/data/px4_ulog/sample_log_small.ulg, 0.9 MB, 1 Hz
sensor topics) and a bigger log made here from it: its definitions and subscriptions verbatim,
then ``--seconds`` one-second blocks, each holding sensor_accel and sensor_gyro x 3 at 1 kHz,
sensor_mag x 2 at 100 Hz, sensor_combined at 250 Hz (records of the real log's layouts, with
fresh times and noise) and the real log's first 2,000 other data messages (attitude,
actuators, estimator, ...), as the traffic a sensor read must walk past. Each block lists its
topics one after the other (a logger interleaves them by time; a reader does not care).

A "sample" is one three-axis reading of an acc, gyro or mag stream (a sensor_combined message
gives two); temperatures are not counted. Times are the best of ``--repeat`` runs after one
warm-up run, in CPU seconds of the process (the machine is shared); "cold" is one read in a fresh
process, imports included (numba's import and cache load, paid once per process).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data" / "px4_ulog" / "sample_log_small.ulg"
RATES = {"sensor_accel": 1000, "sensor_gyro": 1000, "sensor_mag": 100, "sensor_combined": 250}


def make_big(sample: Path, out: Path, seconds: int, seed: int = 1) -> None:
    """A bigger ULog from ``sample``: see the module's docstring."""
    from pyulog import ULog

    from imucal.io.formats import ulog_scan
    from imucal.io.formats.ulog import _flat_dtype

    buf = np.fromfile(sample, dtype=np.uint8)
    offsets, _, _ = ulog_scan.message_offsets(buf, 16)
    kinds = buf[offsets + 2]
    first_data = int(offsets[np.isin(kinds, [ord("A"), ord("L"), ord("C")])][0])
    subs = {}
    for o in offsets[kinds == ord("A")].tolist():
        size = int(buf[o]) | int(buf[o + 1]) << 8
        p = bytes(buf[o + 3:o + 3 + size])
        subs[int.from_bytes(p[1:3], "little")] = (p[3:].split(b"\0")[0].decode(), p[0])
    formats = ULog(str(sample), parse_header_only=True).message_formats
    data = offsets[kinds == ord("D")]
    ids = buf[data + 3].astype(np.int64) | (buf[data + 4].astype(np.int64) << 8)
    sensor_ids = {m for m, (n, _) in subs.items() if n in RATES and (ids == m).any()}
    other = data[~np.isin(ids, list(sensor_ids))][:2000]
    other_bytes = b"".join(
        bytes(buf[o:o + 3 + (int(buf[o]) | int(buf[o + 1]) << 8)]) for o in other.tolist())
    rng = np.random.default_rng(seed)
    with out.open("wb") as fh:
        fh.write(bytes(buf[:first_data]))
        fh.write(b"".join(bytes(buf[o:o + 3 + (int(buf[o]) | int(buf[o + 1]) << 8)])
                          for o in offsets[kinds == ord("A")].tolist()))
        templates = {}
        for m in sorted(sensor_ids):
            name, _ = subs[m]
            rec = _flat_dtype(name, formats)
            first = data[ids == m][0]
            frame = np.dtype([("size", "<u2"), ("type", "u1"), ("id", "<u2"), ("rec", rec)])
            templates[m] = (name, frame, np.frombuffer(bytes(buf[first:first + frame.itemsize]),
                                                       dtype=frame)[0])
        t0 = 30_000_000
        for s in range(seconds):
            chunks = []
            for name, frame, template in templates.values():
                n = RATES[name]
                block = np.repeat(np.array([template], dtype=frame), n)
                stamps = t0 + s * 1_000_000 + np.arange(n, dtype=np.uint64) * (1_000_000 // n)
                rec = block["rec"]
                rec["timestamp"] = stamps + 400
                for f in rec.dtype.names:
                    if f == "timestamp_sample":
                        rec[f] = stamps
                    elif f in ("x", "y", "z") or f.startswith(("gyro_rad", "accelerometer_m")):
                        rec[f] = rec[f] + rng.normal(0.0, 0.01, n).astype(np.float32)
                chunks.append(block.tobytes())
            chunks.append(other_bytes)
            fh.write(b"".join(chunks))


def _samples(streams) -> int:
    return sum(s.samples for s in streams.streams if s.kind != "temp")


def _best(fn, repeat: int) -> tuple[float, object]:
    """The least CPU time (this process, user + sys) of ``repeat`` calls: on a shared machine
    the CPU seconds are what one core spends; wall time counts the neighbours' work too."""
    best, out = float("inf"), None
    for _ in range(repeat):
        t = time.process_time()
        out = fn()
        best = min(best, time.process_time() - t)
    return best, out


def _cold(path: Path, fast: bool) -> float:
    """CPU seconds of one read in a fresh process, imports included (numba's import and cache
    load on the compiled walk; a calibration pays them anyway for its RK4 passes)."""
    code = ("import time; t = time.process_time(); from pathlib import Path; "
            "from imucal.io.formats import ulog; "
            f"ulog.read_streams(Path({str(path)!r}), 'x', None, fast={fast}); "
            "print(time.process_time() - t)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
    return float(out.stdout.strip())


def measure(path: Path, repeat: int, tmp: Path) -> dict:
    from pyulog import ULog

    from imucal.io.formats import ulog

    ulog.read_streams(path, path.name, None)  # warm: numba's import and cache load done
    fast, streams = _best(lambda: ulog.read_streams(path, path.name, None), repeat)
    slow, reference = _best(lambda: ulog.read_streams(path, path.name, None, fast=False),
                            repeat)
    for a, b in zip(streams.streams, reference.streams, strict=True):  # the same arrays
        if a.name != b.name or not (np.array_equal(a.t, b.t)
                                    and np.array_equal(a.values, b.values)):
            raise SystemExit(f"{path.name}: {a.name} differs between the two paths")
    raw, _ = _best(lambda: ULog(str(path), message_name_filter_list=list(ulog.SENSOR_TOPICS)),
                   repeat)
    files = []
    for i, s in enumerate(streams.streams):
        f = tmp / f"{i}.npy"
        np.save(f, np.column_stack([s.t, s.values]))
        files.append(f)
    npy, _ = _best(lambda: [np.load(f) for f in files], repeat)
    return {"file": path.name, "mb": path.stat().st_size / 1e6, "samples": _samples(streams),
            "fast": fast, "pyulog_path": slow, "pyulog_raw": raw, "npy": npy,
            "cold_fast": min(_cold(path, True) for _ in range(2)),
            "cold_slow": min(_cold(path, False) for _ in range(2))}


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=int, default=200)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--sample", type=Path, default=SHARED, help="the shared ULog")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        big = tmp / "big.ulg"
        make_big(args.sample, big, args.seconds)
        for p in (args.sample, big):
            rows.append(measure(p, args.repeat, tmp))
    lines = ["| file | MB | samples | imucal warm (CPU s) | samples/s | "
             "pyulog path warm (CPU s) | samples/s | pyulog alone (CPU s) | .npy (CPU s) | "
             "imucal / .npy | cold: imucal (CPU s) | cold: pyulog path (CPU s) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        n = r["samples"]
        lines.append(
            f"| {r['file']} | {r['mb']:.1f} | {n:,} | {r['fast']:.4f} | "
            f"{n / r['fast'] / 1e6:.2f} M | {r['pyulog_path']:.4f} | "
            f"{n / r['pyulog_path'] / 1e6:.2f} M | {r['pyulog_raw']:.4f} | {r['npy']:.4f} | "
            f"{r['fast'] / r['npy']:.0f}x | {r['cold_fast']:.2f} | {r['cold_slow']:.2f} |")
    text = "\n".join(lines)
    print(text)
    if args.out:
        args.out.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
