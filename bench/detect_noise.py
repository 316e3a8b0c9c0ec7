"""Time (and optionally trace the allocations of) the still-block stage and the noise figures of
one session, in whichever tree's python runs it: main's and a branch's side by side, on a shared
machine, alternating (see bench/detect_noise.md; the whole run: bench/batch_results.md).

    /work/main/.venv/bin/python bench/detect_noise.py /tmp/mn_n60.mat --label main
    .venv/bin/python bench/detect_noise.py /tmp/mn_n60.mat --label branch [--memory | --cpu]

Prints one line: seconds (or MB above what was held before, with ``--memory``) of
``pipeline._still_blocks`` (detection, gaps, saturation, coverage), of ``tune_detector`` within
it, and of ``still_noise`` (``Result.noise``, what calib.json asks for).
"""

from __future__ import annotations

import argparse
import functools
import time
import tracemalloc
from typing import Any

MB = 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("session")
    ap.add_argument("--label", default="")
    ap.add_argument("--memory", action="store_true", help="tracemalloc peaks instead of times")
    ap.add_argument("--cpu", action="store_true",
                    help="this process's CPU seconds instead of wall (a shared machine's load)")
    args = ap.parse_args()
    clock = time.process_time if args.cpu else time.perf_counter

    import imucal.pipeline as pl
    import imucal.result as rm
    from imucal.io.load import load_session

    out: dict[str, float] = {}
    peaks: list[int] = []  # absolute peaks of the probes run so far (a nested one resets it)

    def probed(name: str, f: Any) -> Any:
        @functools.wraps(f)
        def g(*a: Any, **k: Any) -> Any:
            if args.memory:
                before, _ = tracemalloc.get_traced_memory()
                tracemalloc.reset_peak()
                seen = len(peaks)
            t = clock()
            result = f(*a, **k)
            if args.memory:
                _, peak = tracemalloc.get_traced_memory()
                peak = max([peak, *peaks[seen:]])
                peaks.append(peak)
                out[name] = max(out.get(name, 0.0), (peak - before) / MB)
            else:
                out[name] = out.get(name, 0.0) + clock() - t
            return result
        return g

    pl._still_blocks = probed("still_blocks", pl._still_blocks)
    pl.tune_detector = probed("tune_detector", pl.tune_detector)
    rm.still_noise = probed("still_noise", rm.still_noise)
    session = load_session(args.session)
    if args.memory:
        tracemalloc.start()
    t = clock()
    result = pl.calibrate(session)
    if not args.memory:
        out["calibrate"] = clock() - t
    _ = result.noise
    unit = "MB" if args.memory else ("s CPU" if args.cpu else "s")
    print(args.label, " ".join(f"{k}={v:.2f}" for k, v in out.items()), unit, flush=True)


if __name__ == "__main__":
    main()
