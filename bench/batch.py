"""Sessions per second and CPU per session: `imucal batch` (1 and 2 LocalCluster workers)
against `imucal calibrate` run once per file (one at a time, and ``--per-file-jobs`` at a time),
on the same files in the same run; how the rate grows with workers; and the memory of each
worker against that of one `imucal calibrate` process.

    .venv/bin/python bench/batch.py [--sessions 12] [--poses 20] [--workers 1,2] [--rate 100]
                                    [--per-file-jobs 2]

Each rate is sessions over the wall time of the whole commands (the batch's includes starting
its cluster); each CPU figure is user + sys of the whole process tree (the batch's workers are
its children, reaped before it exits), over the sessions. ``--poses 100`` gives sessions of
the shared Xsens recording's size (about 8.5 minutes at 100 Hz).
A worker's memory is its peak RSS as the summary rows report it (``worker_peak_mb``: the
largest over each worker's rows); calibrate's is the largest peak RSS of its processes.
The machine is shared: run it twice and read the ratios, not the absolute rates.
"""

from __future__ import annotations

import argparse
import os
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


def timed(cmds: list[list[str]], jobs: int = 1) -> tuple[float, float]:
    """Wall seconds to run every command, ``jobs`` at a time, and their CPU seconds (user + sys
    of each process and the children it reaped, from ``os.wait4``)."""
    t0 = time.perf_counter()
    cpu = 0.0
    pending, running = list(cmds), {}
    while pending or running:
        while pending and len(running) < jobs:
            cmd = pending.pop(0)
            proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
            running[proc.pid] = (proc, cmd)
        pid, status, ru = os.wait4(-1, 0)
        if pid not in running:
            continue
        proc, cmd = running.pop(pid)
        cpu += ru.ru_utime + ru.ru_stime
        if os.waitstatus_to_exitcode(status) != 0:
            raise SystemExit(f"{' '.join(cmd)} failed: {proc.stderr.read()[-500:]!r}")
        proc.stderr.close()
    return time.perf_counter() - t0, cpu


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
    ap.add_argument("--per-file-jobs", type=int, default=2,
                    help="also run calibrate once per file this many at a time (1: only serial)")
    args = ap.parse_args()
    root = Path(tempfile.mkdtemp(prefix="imucal-bench-batch-"))
    try:
        files = make_files(root / "in", args.sessions, args.poses, args.rate)
        n = len(files)
        per_file = [[IMUCAL, "calibrate", str(f), "-o", str(root / f"{f.stem}.json")]
                    for f in files]
        serial, serial_cpu = timed(per_file)
        calib_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
        print(f"{n} sessions of {args.poses} poses at {args.rate:g} Hz; load average "
              f"{os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
        counts = [int(x) for x in args.workers.split(",")]
        print(f"| run | wall s | sessions/s | CPU s per session | rate vs calibrate per file "
              f"| rate vs {counts[0]} worker(s) | peak MB per process |")
        print("|---|---|---|---|---|---|---|")
        print(f"| calibrate once per file | {serial:.1f} | {n / serial:.2f} | "
              f"{serial_cpu / n:.3f} | 1.00x | | {calib_mb:.0f} |")
        if args.per_file_jobs > 1:
            wall, cpu = timed(per_file, jobs=args.per_file_jobs)
            print(f"| calibrate once per file, {args.per_file_jobs} at a time | {wall:.1f} | "
                  f"{n / wall:.2f} | {cpu / n:.3f} | {serial / wall:.2f}x | | {calib_mb:.0f} |")
        first = None
        for w in counts:
            out = root / f"out{w}"
            wall, cpu = timed([[IMUCAL, "batch", str(root / "in" / "*" / "*.mat"), "--out-dir",
                                str(out), "--workers", str(w), "--force"]])
            first = first or wall
            mem = ", ".join(f"{m:.0f}" for m in worker_memory(out))
            print(f"| batch, {w} worker(s) | {wall:.1f} | {n / wall:.2f} | {cpu / n:.3f} | "
                  f"{serial / wall:.2f}x | {first / wall:.2f}x | {mem} |")
    finally:
        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
