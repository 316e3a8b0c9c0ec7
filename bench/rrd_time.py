"""Wall time of writing a session's recording (``viewer.recording.save_recording``) and what it
adds to the process's peak RSS, for this tree and another (main) in turn, in one run: the
machine is shared, so only ratios measured together mean anything.

    .venv/bin/imucal synth /tmp/s60.mat --minutes 60 --acc-rate 1000
    git archive main | tar -x -C /tmp/main_tree
    .venv/bin/python bench/rrd_time.py /tmp/s60.mat --other /tmp/main_tree --rounds 2

Each round runs one process per tree, alternating: it loads and calibrates the session (not
timed), then writes the recording ``--repeat`` times, each from a result with nothing cached
(``Result.calibrated`` dropped: main makes it for the recording). The peak RSS increase is the
first write's (``ru_maxrss`` after it less before it).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

CHILD = r"""
import json, resource, sys, time
import imucal
from viewer.recording import save_recording
session, out, repeat = sys.argv[1], sys.argv[2], int(sys.argv[3])
r = imucal.calibrate(imucal.load_session(session))
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
times, rss = [], None
for _ in range(repeat):
    for cached in ("calibrated", "noise"):
        r.__dict__.pop(cached, None)
    t0 = time.perf_counter()
    save_recording(r, out)
    times.append(time.perf_counter() - t0)
    if rss is None:
        rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - base
print(json.dumps({"times": times, "rss_add_mb": rss / 1024, "base_mb": base / 1024}))
"""


def run(tree: Path, session: str, repeat: int) -> dict:
    with tempfile.TemporaryDirectory() as d:
        env = dict(os.environ, PYTHONPATH=str(tree))
        out = subprocess.run([sys.executable, "-c", CHILD, session, f"{d}/x.rrd", str(repeat)],
                             env=env, cwd=d, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("session")
    ap.add_argument("--other", required=True, help="the tree to compare with (main)")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    trees = {"main": Path(args.other).resolve(), "this": ROOT}
    got: dict[str, list[dict]] = {k: [] for k in trees}
    for i in range(args.rounds):
        for name, tree in (trees.items() if i % 2 == 0 else reversed(trees.items())):
            got[name].append(run(tree, args.session, args.repeat))
            print(name, got[name][-1], flush=True)
    best = {k: min(t for g in v for t in g["times"]) for k, v in got.items()}
    rss = {k: max(g["rss_add_mb"] for g in v) for k, v in got.items()}
    print("| tree | .rrd wall s (min of all) | each | peak RSS added by the .rrd, MB |")
    print("|---|---|---|---|")
    for k in trees:
        each = ", ".join(f"{t:.1f}" for g in got[k] for t in g["times"])
        print(f"| {k} | {best[k]:.1f} | {each} | {rss[k]:.0f} |")
    print(f"ratio this/main: {best['this'] / best['main']:.2f}")


if __name__ == "__main__":
    main()
