"""Sessions per second: `imucal batch` (1 and 2 LocalCluster workers) against `imucal calibrate`
run once per file, on the same files in the same run; how the rate grows with workers; and
the memory of each worker against that of one `imucal calibrate` process.

    .venv/bin/python bench/batch.py [--sessions 12] [--poses 20] [--workers 1,2] [--rate 100]

Each figure is wall time of the whole command (the batch's includes starting its cluster).
A worker's memory is its peak RSS as the summary rows report it (``worker_peak_mb``: the
largest over each worker's rows); calibrate's is the largest peak RSS of its processes.
The machine is shared: run it twice and read the ratios, not the absolute rates.
"""

from __future__ import annotations

import argparse
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

IMUCAL = str(Path(sys.executable).with_name("imucal"))


def make_files(root: Path, n: int, poses: int, rate: float) -> list[Path]:
    from imucal.io.export import write_session_mat
    from imucal.synth import make_session

    files = []
    for i in range(n):
        device = root / f"dev{i % 3}"
        device.mkdir(parents=True, exist_ok=True)
        sess, _ = make_session(poses=poses, seed=i, acc_rate=rate)
        path = device / f"s{i:03d}.mat"
        write_session_mat(path, sess)
        files.append(path)
    return files


def timed(cmd: list[str]) -> float:
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}): {proc.stderr[-500:]}")
    return time.perf_counter() - t0


def worker_memory(out: Path) -> list[float]:
    """Each worker's peak RSS (MB), from the summary rows."""
    import polars as pl

    df = pl.read_parquet(out / "summary.parquet").filter(pl.col("status") == "ok")
    peaks = df.group_by("worker").agg(pl.col("worker_peak_mb").max()).sort("worker_peak_mb")
    return peaks["worker_peak_mb"].to_list()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sessions", type=int, default=12)
    ap.add_argument("--poses", type=int, default=20)
    ap.add_argument("--workers", default="1,2")
    ap.add_argument("--rate", type=float, default=100.0, help="sample rate of the sessions, Hz")
    args = ap.parse_args()
    root = Path(tempfile.mkdtemp(prefix="imucal-bench-batch-"))
    try:
        files = make_files(root / "in", args.sessions, args.poses, args.rate)
        n = len(files)
        serial = sum(timed([IMUCAL, "calibrate", str(f), "-o", str(root / f"{f.stem}.json")])
                     for f in files)
        calib_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
        print(f"{n} sessions of {args.poses} poses at {args.rate:g} Hz")
        counts = [int(x) for x in args.workers.split(",")]
        print(f"| run | wall s | sessions/s | rate vs calibrate per file | rate vs {counts[0]} "
              "worker(s) | peak MB per process |")
        print("|---|---|---|---|---|---|")
        print(f"| calibrate once per file | {serial:.1f} | {n / serial:.2f} | 1.00x | | "
              f"{calib_mb:.0f} |")
        first = None
        for w in counts:
            out = root / f"out{w}"
            wall = timed([IMUCAL, "batch", str(root / "in" / "*" / "*.mat"), "--out-dir",
                          str(out), "--workers", str(w), "--force"])
            first = first or wall
            mem = ", ".join(f"{m:.0f}" for m in worker_memory(out))
            print(f"| batch, {w} worker(s) | {wall:.1f} | {n / wall:.2f} | "
                  f"{serial / wall:.2f}x | {first / wall:.2f}x | {mem} |")
    finally:
        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
