"""CPU seconds of the noise figures, the clock's medians, the order statistics, the saturation
runs, the quality figures and the recording guide inside one ``calibrate`` (issue 12), main's
install against a branch's, alternating, and the whole ``imucal calibrate`` under
``/usr/bin/time -v`` (see bench/stats_speed.md).

    .venv/bin/python bench/stats_speed.py probe /tmp/mn_n60.mat   # one run, this tree
    .venv/bin/python bench/stats_speed.py compare --rounds 2 /tmp/mn_n60.mat /tmp/mn_n360.mat \\
        [--main /work/main/.venv/bin --branch .venv/bin]

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
    args = ap.parse_args()
    probe(args.session) if args.cmd == "probe" else compare(args)


if __name__ == "__main__":
    main()
