"""Sessions per second: `imucal batch` (1 and 2 LocalCluster workers) against `imucal calibrate`
run once per file, on the same files in the same run.

    .venv/bin/python bench/batch.py [--sessions 12] [--poses 20] [--workers 1,2]

Each figure is wall time of the whole command (the batch's includes starting its cluster).
The machine is shared: run it twice and read the ratio, not the absolute rates.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

IMUCAL = str(Path(sys.executable).with_name("imucal"))


def make_files(root: Path, n: int, poses: int) -> list[Path]:
    from imucal.io.export import write_session_mat
    from imucal.synth import make_session

    files = []
    for i in range(n):
        device = root / f"dev{i % 3}"
        device.mkdir(parents=True, exist_ok=True)
        sess, _ = make_session(poses=poses, seed=i)
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sessions", type=int, default=12)
    ap.add_argument("--poses", type=int, default=20)
    ap.add_argument("--workers", default="1,2")
    args = ap.parse_args()
    root = Path(tempfile.mkdtemp(prefix="imucal-bench-batch-"))
    try:
        files = make_files(root / "in", args.sessions, args.poses)
        n = len(files)
        serial = sum(timed([IMUCAL, "calibrate", str(f), "-o", str(root / f"{f.stem}.json")])
                     for f in files)
        print(f"{n} sessions of {args.poses} poses")
        print(f"calibrate once per file  {serial:7.1f} s  {n / serial:6.2f} sessions/s")
        for w in (int(x) for x in args.workers.split(",")):
            out = root / f"out{w}"
            wall = timed([IMUCAL, "batch", str(root / "in" / "*" / "*.mat"), "--out-dir",
                          str(out), "--workers", str(w), "--force"])
            print(f"batch, {w} worker(s)       {wall:7.1f} s  {n / wall:6.2f} sessions/s  "
                  f"ratio {serial / wall:5.2f}x")
    finally:
        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
