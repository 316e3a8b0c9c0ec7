"""Benchmark of ``imucal noise``: peak memory against the length of a still recording.

    .venv/bin/python bench/noise.py                 # 15 and 60 minutes at 1 kHz
    .venv/bin/python bench/noise.py --minutes 5 20  # other lengths

For each length it writes a still recording at 1 kHz as CSV (``t,ax,ay,az,gx,gy,gz``: white
noise and a random walk on gravity and a zero rate; written with polars a block at a time, so
the generator itself stays small) into a temporary directory, then runs the command line
``imucal noise FILE --gyro-unit rad/s --out noise.json`` as a child process and reads its wall
time, CPU time and peak RSS from ``os.wait4``. The figure of merit is the ratio of the peak RSS
of the longest to the shortest file: 1.0 is memory that does not grow with the recording. The
white noise densities recovered are printed beside the truth, as a check that the run did the
work. Results go to stdout and to ``bench/noise_results.md`` (``--out``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
IMUCAL = shutil.which("imucal", path=str(Path(sys.executable).parent)) or "imucal"
RATE = 1000.0
ACC_N, ACC_K = 2e-3, 2e-4  # m/s^2/sqrt(Hz), m/s^3/sqrt(Hz)
GYRO_N, GYRO_K = 1e-4, 2e-5  # rad/s/sqrt(Hz), rad/s^2/sqrt(Hz)


def write_still(path: Path, minutes: float, seed: int = 0, block: int = 200_000) -> int:
    """A still recording at RATE, written a block of rows at a time; returns the bytes."""
    import polars as pl

    rng = np.random.default_rng(seed)
    n = int(minutes * 60 * RATE)
    dt = 1.0 / RATE
    walk = np.zeros(6)
    with path.open("wb") as f:
        for lo in range(0, n, block):
            m = min(block, n - lo)
            steps = rng.normal(size=(m, 6)) * np.sqrt(dt) * ([ACC_K] * 3 + [GYRO_K] * 3)
            w = np.cumsum(steps, axis=0) + walk
            walk = w[-1]
            white = rng.normal(size=(m, 6)) / np.sqrt(dt) * ([ACC_N] * 3 + [GYRO_N] * 3)
            x = w + white + [0.1, -0.2, 9.81, 0.01, 0.0, -0.02]
            t = (lo + np.arange(m)) * dt
            df = pl.DataFrame({"t": t, **{c: x[:, i] for i, c in enumerate(
                ("ax", "ay", "az", "gx", "gy", "gz"))}})
            df.write_csv(f, include_header=lo == 0, float_precision=6)
    return path.stat().st_size


def run_noise(path: Path, out: Path) -> dict:
    t0 = time.perf_counter()
    p = subprocess.Popen([IMUCAL, "noise", str(path), "--gyro-unit", "rad/s", "--out",
                          str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    _, status, ru = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t0
    stdout, stderr = p.stdout.read().decode(), p.stderr.read().decode()
    p.stdout.close()
    p.stderr.close()
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"imucal noise failed: {stderr}")
    doc = json.loads(out.read_text())["noise"]
    return {"wall_s": wall, "cpu_s": ru.ru_utime + ru.ru_stime,
            "maxrss_mb": ru.ru_maxrss / 1024.0, "source": doc["source"],
            "acc_white": doc["accelerometer"]["white_noise_density"],
            "gyro_white": doc["gyroscope"]["white_noise_density"],
            "acc_rw": doc["accelerometer"]["random_walk"],
            "gyro_rw": doc["gyroscope"]["random_walk"], "stdout": stdout}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--minutes", type=float, nargs="+", default=[15.0, 60.0])
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "noise_results.md")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory(prefix="imucal-bench-noise-") as tmp:
        for minutes in args.minutes:
            path = Path(tmp) / f"still_{minutes:g}min.csv"
            t0 = time.perf_counter()
            size = write_still(path, minutes)
            gen = time.perf_counter() - t0
            r = run_noise(path, Path(tmp) / "noise.json")
            r |= {"minutes": minutes, "rows": int(minutes * 60 * RATE), "mb": size / 1e6,
                  "generate_s": gen}
            rows.append(r)
            print(f"{minutes:g} min: {size / 1e6:.0f} MB CSV, {r['wall_s']:.1f} s wall, "
                  f"{r['cpu_s']:.1f} s CPU, peak RSS {r['maxrss_mb']:.0f} MB", flush=True)
            path.unlink()
    ratio = rows[-1]["maxrss_mb"] / rows[0]["maxrss_mb"]
    length_ratio = rows[-1]["rows"] / rows[0]["rows"]
    signal_mb = rows[-1]["rows"] * 6 * 8 / 1e6
    lines = [
        "# imucal noise: peak memory against recording length",
        "",
        f"{platform.node()} ({os.cpu_count()} cores), Python {platform.python_version()}, "
        f"{time.strftime('%Y-%m-%d')}. Regenerate: `.venv/bin/python bench/noise.py`.",
        "",
        "Still CSV at 1 kHz (t, 3 accelerometer and 3 gyroscope columns, 6 decimals), "
        "`imucal noise FILE --gyro-unit rad/s --out noise.json` as a child process (os.wait4).",
        "",
        "| length | rows | CSV (MB) | wall (s) | CPU (s) | peak RSS (MB) "
        "| acc white (m/s^2/sqrt(Hz)) | gyro white (rad/s/sqrt(Hz)) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(f"| {r['minutes']:g} min | {r['rows']:,} | {r['mb']:.0f} | "
                     f"{r['wall_s']:.1f} | {r['cpu_s']:.1f} | {r['maxrss_mb']:.0f} | "
                     + ", ".join(f"{v:.4g}" for v in r["acc_white"]) + " | "
                     + ", ".join(f"{v:.4g}" for v in r["gyro_white"]) + " |")
    lines += [
        "",
        f"Peak RSS ratio, {rows[-1]['minutes']:g} min / {rows[0]['minutes']:g} min: "
        f"**{ratio:.2f}** for {length_ratio:.0f}x the samples (the whole "
        f"{rows[-1]['minutes']:g}-minute signal alone would be {signal_mb:.0f} MB of float64).",
        f"Truth: white {ACC_N:g} m/s^2/sqrt(Hz) and {GYRO_N:g} rad/s/sqrt(Hz); random walk "
        f"{ACC_K:g} m/s^3/sqrt(Hz) and {GYRO_K:g} rad/s^2/sqrt(Hz) (recovered, longest: "
        + ", ".join(f"{v:.3g}" if v is not None else "n/a" for v in rows[-1]["acc_rw"]) + "; "
        + ", ".join(f"{v:.3g}" if v is not None else "n/a" for v in rows[-1]["gyro_rw"]) + ").",
        "",
    ]
    text = "\n".join(lines)
    print(text)
    args.out.write_text(text)


if __name__ == "__main__":
    main()
