"""Log readers' speed: samples per second read from each log format (imucal.io.formats), against
reading the same samples from a ``.npy`` file in the same run, pinned to one core.

    .venv/bin/python bench/read_speed.py [--messages 500000] [--repeat 3] [--keep DIR]
                                         [--formats ros2-db3,mcap] [--memory-mb 300]

One function per format (``FORMATS``): it writes (or finds in ``--keep``) a log of ``n`` IMU
samples with that format's own writer and returns the path; the bench then times
``imucal.io.formats.read_streams`` on it (best of ``--repeat``; the SHA-256 the reader computes
in a thread is included, on the same core) and ``np.load`` of a (n, 7) float64 array of the same
time and values. A sample here is one IMU message: one accelerometer and one gyroscope triad
(so "samples" of streams are twice the figure). The reference column is the format's library
deserialising message by message (rosbags' own deserializer for ROS), timed on a slice.

To add a format (ULog, DataFlash): write ``def make_ulog(root, n) -> Path`` and add it to
``FORMATS``; everything else is shared.

``--memory-mb M`` adds a second table: peak RSS of a fresh process reading a bag that holds a
small IMU topic (30,000 messages, about 11 MB) beside an M-MB topic of other messages, against
the same process that only imports the readers: what the reader keeps must follow the IMU
topic, not the file.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests" / "io"))  # bags.py: bags written with rosbags' writers


def signals(n: int, seed: int = 7) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """n samples at 1 kHz from 2023-11-14 (Unix time), nanosecond jitter, noisy values."""
    rng = np.random.default_rng(seed)
    t_ns = 1_700_000_000 * 10**9 + np.arange(n, dtype=np.int64) * 1_000_000 \
        + rng.integers(0, 1000, n)
    acc = rng.normal([0, 0, 9.81], 0.05, (n, 3))
    gyro = rng.normal(0, 0.01, (n, 3))
    return t_ns, acc, gyro


def _ros(root: Path, n: int, key: str) -> Path:
    from bags import write_bag

    bag = root / (f"imu_{n}.bag" if key == "ros1" else f"imu_{key}_{n}")
    target = bag if key == "ros1" else bag / f"{bag.name}.{'mcap' if key == 'mcap' else 'db3'}"
    if not target.exists():
        shutil.rmtree(bag, ignore_errors=True)
        t_ns, acc, gyro = signals(n)
        write_bag(bag, key, acc, gyro, t_ns)
    return target


def make_ros1(root: Path, n: int) -> Path:
    return _ros(root, n, "ros1")


def make_ros2_db3(root: Path, n: int) -> Path:
    return _ros(root, n, "ros2")


def make_mcap(root: Path, n: int) -> Path:
    return _ros(root, n, "mcap")


def ros_reference(path: Path, limit: int) -> float:
    """Messages per second through rosbags' AnyReader and per-message deserialize."""
    from rosbags.highlevel import AnyReader

    with AnyReader([path if path.suffix == ".bag" else path.parent]) as reader:
        conns = [c for c in reader.connections if c.msgtype == "sensor_msgs/msg/Imu"]
        t0 = time.perf_counter()
        count = 0
        for conn, _, raw in reader.messages(conns):
            msg = reader.deserialize(raw, conn.msgtype)
            _ = (msg.header.stamp, msg.linear_acceleration, msg.angular_velocity)
            count += 1
            if count == limit:
                break
        return count / (time.perf_counter() - t0)


# name -> (make the file, the reference reader's messages per second or None)
FORMATS: dict[str, tuple[Callable[[Path, int], Path], Callable[[Path, int], float] | None]] = {
    "ros2-db3": (make_ros2_db3, ros_reference),
    "mcap": (make_mcap, ros_reference),
    "ros1": (make_ros1, ros_reference),
}


MEMORY_KEYS = {"ros1": "ros1", "ros2-db3": "ros2", "mcap": "mcap"}
# Peak RSS as VmHWM: ru_maxrss of a child started by fork and exec keeps its parent's peak.
_PEAK = """
import sys
from pathlib import Path
from imucal.io.formats import read_streams, sniff
import apsw, rosbags.rosbag1, rosbags.rosbag2, rosbags.typesys  # imported before the baseline

def hwm():
    with open("/proc/self/status") as fh:
        return next(int(x.split()[1]) for x in fh if x.startswith("VmHWM:"))

before = hwm()
if sys.argv[1] != "-":
    p = Path(sys.argv[1])
    head = open(p, "rb").read(64) if p.is_file() else b""  # a ROS 2 bag may be a directory
    ss = read_streams(p, sniff(head, p), p.name)
    assert ss.streams[0].samples == 30000
print(before, hwm())
"""


def memory(root: Path, name: str, mb: int) -> dict[str, float | str]:
    """Peak RSS (MB) reading a bag of a small IMU topic beside an ``mb``-MB other topic."""
    import subprocess

    from bags import write_bag

    key = MEMORY_KEYS[name]
    n = 30_000
    bag = root / (f"big_{mb}.bag" if key == "ros1" else f"big_{key}_{mb}")
    t_ns, acc, gyro = signals(n)
    if not bag.exists():
        write_bag(bag, key, acc, gyro, t_ns, extra=["/camera/blob"], extra_bytes=1 << 20,
                  extra_every=max(1, n // mb))
    size = sum(f.stat().st_size for f in ([bag] if bag.is_file() else bag.iterdir()))

    def peak(arg: str) -> tuple[float, float]:
        out = subprocess.run([sys.executable, "-c", _PEAK, arg], capture_output=True,
                             text=True, check=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
        before, after = out.stdout.split()
        return int(before) / 1024, int(after) / 1024

    _, base = peak("-")
    before, after = peak(str(bag))
    return {"format": name, "file_MB": round(size / 1e6), "imu_MB": round(n * 360 / 1e6, 1),
            "imports_peak_MB": round(base), "read_peak_MB": round(after),
            "added_MB": round(after - before)}


def table(rows: list[dict]) -> None:
    cols = list(rows[0])
    print("| " + " | ".join(cols) + " |")
    print("|" + "---|" * len(cols))
    for r in rows:
        print("| " + " | ".join(str(r[c]) for c in cols) + " |")


def best(fn: Callable[[], object], repeat: int) -> tuple[float, float, object]:
    """Best wall and CPU seconds of ``repeat`` runs, and the last result."""
    wall = cpu = float("inf")
    out = None
    for _ in range(repeat):
        w0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        wall = min(wall, time.perf_counter() - w0)
        cpu = min(cpu, time.process_time() - c0)
    return wall, cpu, out


def run(name: str, root: Path, n: int, repeat: int) -> dict[str, float | str | int]:
    from imucal.io.formats import read_streams, sniff

    make, reference = FORMATS[name]
    path = make(root, n)
    key = sniff(path.read_bytes()[:64], path)
    assert key is not None, path
    wall, cpu, ss = best(lambda: read_streams(path, key, path.name), repeat)
    acc = ss.of_kind("acc")[0]  # type: ignore[attr-defined]
    gyro = ss.of_kind("gyro")[0]  # type: ignore[attr-defined]
    assert acc.samples == gyro.samples == n, (acc.samples, n)

    npy = root / f"{name}_{n}.npy"
    np.save(npy, np.column_stack([acc.t, acc.values, gyro.values]))
    npy_wall, _, arr = best(lambda: np.load(npy), repeat)
    assert np.array_equal(arr[:, 1:4], acc.values)  # type: ignore[index]
    ref = reference(path, min(n, 20_000)) if reference else float("nan")
    return {"format": name, "samples": n, "MB": round(path.stat().st_size / 1e6, 1),
            "wall_s": round(wall, 3), "cpu_s": round(cpu, 3),
            "samples_per_s": round(n / wall), "samples_per_cpu_s": round(n / cpu),
            "npy_s": round(npy_wall, 4),
            "x_npy": round(wall / npy_wall, 1), "reference_per_s": round(ref),
            "x_reference": round((n / wall) / ref, 1)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--messages", type=int, default=500_000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--keep", type=Path, help="write and reuse the logs here")
    ap.add_argument("--formats", default=",".join(FORMATS))
    ap.add_argument("--memory-mb", type=int, default=0, help="also the memory table")
    ap.add_argument("--cpu", type=int, default=None, help="core to pin to (default: the first "
                    "allowed)")
    args = ap.parse_args()
    allowed = sorted(os.sched_getaffinity(0))
    os.sched_setaffinity(0, {args.cpu if args.cpu is not None else allowed[0]})
    root = args.keep or Path(tempfile.mkdtemp(prefix="imucal-read-speed-"))
    root.mkdir(parents=True, exist_ok=True)
    names = args.formats.split(",")
    try:
        table([run(name, root, args.messages, args.repeat) for name in names])
        if args.memory_mb:
            print()
            table([memory(root, name, args.memory_mb)
                   for name in names if name in MEMORY_KEYS])
    finally:
        if args.keep is None:
            shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
