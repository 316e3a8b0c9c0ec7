"""A long session as a whole process, this tree against a baseline install, in the same run
(issue 12: a 6-hour 1 kHz session under 1.5 GB and 30 s).

    .venv/bin/imucal synth /tmp/s360.mat --minutes 360 --acc-rate 1000
    git worktree add --detach /tmp/base <commit> && python3 -m venv /tmp/base/.venv \\
        && /tmp/base/.venv/bin/pip install -e /tmp/base
    .venv/bin/python bench/long_session.py /tmp/s360.mat --baseline /tmp/base/.venv/bin/imucal

Runs ``imucal calibrate SESSION -o X.json`` (and with ``--rrd``, the recording too) under
``/usr/bin/time -v``, the two commands in turn (A B A B ...), and prints per command the median
wall, user and system seconds and peak RSS, and the ratios this tree / baseline pair by pair;
the two calib.json are compared (the clock's lines aside): every number's largest relative
difference, every other value equal.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]
FIELDS = {"wall": r"Elapsed \(wall clock\) time \(h:mm:ss or m:ss\): (\S+)",
          "user": r"User time \(seconds\): (\S+)", "sys": r"System time \(seconds\): (\S+)",
          "rss_mb": r"Maximum resident set size \(kbytes\): (\d+)"}


def _seconds(text: str) -> float:
    parts = [float(p) for p in text.split(":")]
    return sum(p * 60 ** i for i, p in enumerate(reversed(parts)))


def run(imucal: str, session: Path, out: Path, rrd: bool) -> dict[str, float]:
    cmd = ["/usr/bin/time", "-v", imucal, "calibrate", str(session), "-o", str(out)]
    if rrd:
        cmd += ["--rrd", str(out.with_suffix(".rrd"))]
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode:
        sys.exit(f"{imucal} failed ({p.returncode}): {p.stderr.strip().splitlines()[-1]}")
    got = {k: re.search(rx, p.stderr).group(1) for k, rx in FIELDS.items()}
    return {"wall": _seconds(got["wall"]), "user": float(got["user"]),
            "sys": float(got["sys"]), "rss_mb": int(got["rss_mb"]) / 1024}


def _calib(path: Path) -> dict:
    d = json.loads(path.read_text())
    return {k: v for k, v in d.items() if k not in ("created", "elapsed_s", "software")}


def largest_difference(a, b, where: str = "") -> tuple[float, str]:
    """The largest relative difference between two calib.json trees' numbers and where it is
    (``inf`` where they differ otherwise: a key, a length, a string, a flag)."""
    if isinstance(a, dict) and isinstance(b, dict):
        if a.keys() != b.keys():
            return math.inf, f"{where}: keys {sorted(a.keys() ^ b.keys())}"
        found = [largest_difference(a[k], b[k], f"{where}/{k}") for k in a]
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return math.inf, f"{where}: length {len(a)} against {len(b)}"
        found = [largest_difference(x, y, f"{where}[{i}]") for i, (x, y) in enumerate(zip(a, b))]
    elif (isinstance(a, (int, float)) and isinstance(b, (int, float))
          and not isinstance(a, bool) and not isinstance(b, bool)):
        if a == b or (math.isnan(a) and math.isnan(b)):
            return 0.0, where
        return abs(a - b) / max(abs(a), abs(b)), where
    else:
        same = a == b and type(a) is type(b)
        return (0.0, where) if same else (math.inf, f"{where}: {a!r} against {b!r}")
    return max(found, key=lambda f: f[0], default=(0.0, where))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("session", type=Path)
    ap.add_argument("--baseline", required=True, help="the baseline's imucal executable")
    ap.add_argument("-n", type=int, default=3, help="runs of each")
    ap.add_argument("--rrd", action="store_true", help="write the recording too")
    args = ap.parse_args()
    this = str(HERE / ".venv" / "bin" / "imucal")
    runs: dict[str, list[dict[str, float]]] = {"this": [], "baseline": []}
    with tempfile.TemporaryDirectory() as tmp:
        outs = {name: Path(tmp) / f"{name}.json" for name in runs}
        for _ in range(args.n):
            for name, exe in (("this", this), ("baseline", args.baseline)):
                runs[name].append(run(exe, args.session, outs[name], args.rrd))
        diff, where = largest_difference(_calib(outs["this"]), _calib(outs["baseline"]))
    same = "identical" if diff == 0 else f"largest relative difference {diff:.1e} at {where}"
    print(f"{args.session.name}, {args.n} runs each, alternating"
          f"{', with the .rrd' if args.rrd else ''}; calib.json: {same}\n")
    print("| figure | this tree | baseline | ratio (median of pairs) |")
    print("|---|---|---|---|")
    for key in FIELDS:
        a = statistics.median(r[key] for r in runs["this"])
        b = statistics.median(r[key] for r in runs["baseline"])
        ratio = statistics.median(x[key] / y[key] for x, y in zip(runs["this"],
                                                                  runs["baseline"]))
        print(f"| {key} | {a:.1f} | {b:.1f} | {ratio:.2f} |")


if __name__ == "__main__":
    main()
