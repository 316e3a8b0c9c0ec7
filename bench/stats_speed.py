"""CPU seconds of the noise figures, the clock's medians, the order statistics, the saturation
runs, the quality figures and the recording guide inside one ``calibrate`` (issue 12), main's
install against a branch's, alternating, and the whole ``imucal calibrate`` under
``/usr/bin/time -v`` (see bench/stats_speed.md).

    .venv/bin/python bench/stats_speed.py probe /tmp/mn_n60.mat   # one run, this tree
    .venv/bin/python bench/stats_speed.py compare --rounds 2 /tmp/mn_n60.mat /tmp/mn_n360.mat \\
        [--main /work/main/.venv/bin --branch .venv/bin] > bench/stats_speed.jsonl
    .venv/bin/python bench/stats_speed.py table bench/stats_speed.jsonl   # the note's tables
    .venv/bin/python bench/stats_speed.py pair /tmp/mn_n360.mat   # still_noise, one pass or two

``probe`` prints one JSON line: per function, the CPU seconds (``time.process_time``: user and
system, so a re-read of a spilled signal counts) summed over its calls, and the calls. The 2
cores are shared: CPU seconds, not wall time, are the figure to read.
"""

from __future__ import annotations

import argparse
import functools
import importlib
import json
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

# (module, attribute) -> the name reported; every place a function is looked up from is patched
# (a name imported into another module is a reference of its own).
PROBES = {
    ("imucal.result", "still_noise"): "still_noise",
    ("imucal.stages.noise", "_pooled"): "pooled_allan_variance",
    ("imucal.stages.noise", "chunked_median"): "noise clock rate",
    ("imucal.session", "median_step"): "median_step",
    ("imucal.stages.detect", "median_step"): "median_step",
    ("imucal.stages.sanity", "median_step"): "median_step",
    ("imucal.session", "ranked_values"): "ranked_values",
    ("imucal.stages.sanity", "ranked_values"): "ranked_values",
    ("imucal.io.units", "ranked_values"): "ranked_values (io.units)",
    ("imucal.pipeline", "saturated_runs"): "saturated_runs",
    ("imucal.stages.saturation", "saturated_runs"): "saturated_runs",
    ("imucal.stages.guide", "saturated_runs"): "saturated_runs",
    ("imucal.stages.guide", "axis_saturated_runs"): "saturated_runs",
    ("imucal.stages.guide", "gyro_full_scale"): "guide: gyro_full_scale",
    ("imucal.stages.guide", "_peak_rates"): "guide: _peak_rates",
    ("imucal.pipeline", "recording_guide"): "recording_guide",
    ("imucal.pipeline", "quality_figures"): "quality_figures",
}


def probe(path: str) -> None:
    out: dict[str, list[float]] = {}

    def probed(name: str, f: Any) -> Any:
        @functools.wraps(f)
        def g(*a: Any, **k: Any) -> Any:
            t = time.process_time()
            try:
                return f(*a, **k)
            finally:
                rec = out.setdefault(name, [0.0, 0])
                rec[0] += time.process_time() - t
                rec[1] += 1
        return g

    for (mod, attr), name in PROBES.items():
        m = importlib.import_module(mod)
        if hasattr(m, attr):
            setattr(m, attr, probed(name, getattr(m, attr)))
    from imucal.io.load import load_session
    from imucal.pipeline import calibrate

    t0 = time.process_time()
    session = load_session(path)
    t1 = time.process_time()
    result = calibrate(session)
    t2 = time.process_time()
    _ = result.noise  # what calib.json asks for
    t3 = time.process_time()
    figures = {k: round(v[0], 3) for k, v in out.items()}
    calls = {k: v[1] for k, v in out.items()}
    print(json.dumps({"load": round(t1 - t0, 3), "calibrate": round(t2 - t1, 3),
                      "noise": round(t3 - t2, 3), "cpu": figures, "calls": calls}), flush=True)


def _time_v(bin_dir: str, path: str, out: str) -> dict[str, float]:
    p = subprocess.run(["/usr/bin/time", "-v", f"{bin_dir}/imucal", "calibrate", path, "-o", out],
                       capture_output=True, text=True)
    err = p.stderr

    def grab(label: str) -> float:
        m = re.search(rf"{re.escape(label)}: ([\d.]+)", err)
        return float(m.group(1)) if m else float("nan")

    return {"user": grab("User time (seconds)"), "sys": grab("System time (seconds)"),
            "rss_mb": grab("Maximum resident set size (kbytes)") / 1024, "rc": p.returncode}


def compare(args: argparse.Namespace) -> None:
    here = Path(__file__).resolve()
    for r in range(args.rounds):
        for path in args.sessions:
            for label, bin_dir in (("main", args.main), ("branch", args.branch)):
                py = f"{bin_dir}/python"
                p = subprocess.run([py, str(here), "probe", path], capture_output=True, text=True)
                line = p.stdout.strip().splitlines()[-1] if p.stdout.strip() else p.stderr[-500:]
                print(json.dumps({"round": r, "session": Path(path).name, "label": label,
                                  "probe": json.loads(line) if line.startswith("{") else line}),
                      flush=True)
                tv = _time_v(bin_dir, path, f"/tmp/stats_speed_{label}.json")
                print(json.dumps({"round": r, "session": Path(path).name, "label": label,
                                  "time_v": tv}), flush=True)


def table(path: str) -> None:
    """Markdown tables of a ``compare`` run: per session and figure, each round's CPU
    seconds for main and the branch and the ratio of their sums."""
    rows = [json.loads(line) for line in open(path) if line.startswith("{")]
    cpu: dict = {}
    calls: dict = {}
    tv: dict = {}
    for r in rows:
        key = (r["session"], r["label"])
        if isinstance(r.get("probe"), dict):
            p = r["probe"]
            figs = {"calibrate()": p["calibrate"], "Result.noise": p["noise"], **p["cpu"]}
            for k, v in figs.items():
                cpu.setdefault(key, {}).setdefault(k, []).append(v)
            calls[key] = p["calls"]
        if "time_v" in r:
            for k, v in r["time_v"].items():
                tv.setdefault(key, {}).setdefault(k, []).append(v)
    for sess in sorted({k[0] for k in cpu}):
        m, b = cpu.get((sess, "main"), {}), cpu.get((sess, "branch"), {})
        print(f"\n### {sess}: CPU s per round, main and branch\n")
        print("| figure | main | branch | branch/main | calls main -> branch |")
        print("|---|---|---|---|---|")
        for k in sorted(set(m) | set(b), key=lambda k: -sum(m.get(k, [0]))):
            a, c = m.get(k, []), b.get(k, [])
            ratio = f"{sum(c) / sum(a):.2f}" if a and c and sum(a) > 0 else ""
            ca = calls.get((sess, "main"), {}).get(k, "")
            cb = calls.get((sess, "branch"), {}).get(k, "")
            print(f"| {k} | {' '.join(f'{x:.2f}' for x in a)} | "
                  f"{' '.join(f'{x:.2f}' for x in c)} | {ratio} | {ca} -> {cb} |")
        a, c = tv.get((sess, "main")), tv.get((sess, "branch"))
        if a and c:
            def us(d: dict) -> str:
                return " ".join(f"{u:.1f}+{s:.1f}" for u, s in zip(d["user"], d["sys"]))
            ratio = (sum(c["user"]) + sum(c["sys"])) / (sum(a["user"]) + sum(a["sys"]))
            print(f"\n`/usr/bin/time -v imucal calibrate`, user+sys s: main {us(a)}, branch "
                  f"{us(c)}: {ratio:.2f}; max RSS MB main "
                  f"{' '.join(f'{x:.0f}' for x in a['rss_mb'])}, branch "
                  f"{' '.join(f'{x:.0f}' for x in c['rss_mb'])}")


def pair(path: str, rounds: int) -> None:
    """``still_noise`` on one Result, alternating: both sensors in one six-column pass (one
    clock, row getters) against two three-column passes (the gyroscope's clock another
    object, the same values); CPU and wall seconds, and whether the curves are the same."""
    import resource

    import numpy as np

    from imucal.io.load import load_session
    from imucal.pipeline import calibrate
    from imucal.result import StillSignals
    from imucal.stages.noise import still_noise

    r = calibrate(load_session(path))
    src = StillSignals(r.calibration, r.session)

    class Apart:
        def __init__(self, s: StillSignals) -> None:
            self.acc, self.gyro, self.acc_unit, self.t_acc = s.acc, s.gyro, s.acc_unit, s.t_acc
            self.t_gyro = s.t_gyro[:]  # a view: not the accelerometer's clock object

    ref = None
    for _ in range(rounds):
        for name, s in (("paired", src), ("apart", Apart(src))):
            ru0 = resource.getrusage(resource.RUSAGE_SELF)
            c, w = time.process_time(), time.perf_counter()
            rep = still_noise(s, r.block_times)
            c, w = time.process_time() - c, time.perf_counter() - w
            ru1 = resource.getrusage(resource.RUSAGE_SELF)
            ref = ref or rep
            same = all(np.array_equal(getattr(rep, k).curve.avar, getattr(ref, k).curve.avar)
                       for k in ("accelerometer", "gyroscope"))
            print(f"{name}: cpu {c:.2f} s (user {ru1.ru_utime - ru0.ru_utime:.2f}, sys "
                  f"{ru1.ru_stime - ru0.ru_stime:.2f}), wall {w:.2f} s, same {same}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("probe")
    p.add_argument("session")
    c = sub.add_parser("compare")
    c.add_argument("sessions", nargs="+")
    c.add_argument("--rounds", type=int, default=2)
    c.add_argument("--main", default="/work/main/.venv/bin")
    c.add_argument("--branch", default=str(Path(sys.executable).parent))
    t = sub.add_parser("table")
    t.add_argument("jsonl")
    q = sub.add_parser("pair")
    q.add_argument("session")
    q.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args()
    if args.cmd == "probe":
        probe(args.session)
    elif args.cmd == "compare":
        compare(args)
    elif args.cmd == "pair":
        pair(args.session, args.rounds)
    else:
        table(args.jsonl)


if __name__ == "__main__":
    main()
