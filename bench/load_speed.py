"""``load_session`` of a baseline install against this checkout's, measured alternately in the
same run (issue 12's 30-second target; the machine is shared, so only ratios measured side by
side mean much, and CPU seconds more than wall).

    .venv/bin/python bench/load_speed.py --baseline /work/main/.venv/bin --rounds 3 \\
        /tmp/mn_n60.mat /tmp/c60.mat /tmp/mn_n360.mat /tmp/c360.mat

For each session and round: the baseline, this checkout with its default threads (the cores
the process may use) and this checkout in one thread (as a batch worker loads), each in a child
process (``load_speed.py one SESSION [THREADS]``, run by that install's python) that times
``load_session`` alone: wall, CPU user and system (``getrusage``: every thread's), the peak RSS
of the process, and a SHA-256 of the session's arrays (shapes, layout and bytes), which must be
the same for all three. The minimum over the rounds is reported, and the ratios to the baseline.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve()
THIS_BIN = Path(sys.executable).parent


def one(session: str, threads: int | None) -> dict:
    """``load_session(session)`` timed alone (run by the install being measured)."""
    import hashlib

    import numpy as np

    from imucal.io.load import load_session

    kw = {} if threads is None else {"threads": threads}
    r0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
    s = load_session(session, **kw)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_SELF)
    digest = hashlib.sha256()
    for a in (s.acc, s.t_acc, s.gyro, s.t_gyro):
        digest.update(repr(None if a is None else (a.shape, a.dtype.str,
                                                   a.flags.c_contiguous)).encode())
        for lo in range(0, 0 if a is None else len(a), 1 << 16):
            digest.update(np.ascontiguousarray(a[lo:lo + (1 << 16)]).tobytes())
    digest.update(repr((s.acc_unit, s.gyro_unit, s.notes, s.t_gyro is s.t_acc, s.sha256,
                        s.storage)).encode())
    return {"wall": wall, "user": r1.ru_utime - r0.ru_utime, "sys": r1.ru_stime - r0.ru_stime,
            "peak_mb": r1.ru_maxrss / 1024, "sha": digest.hexdigest()[:16]}


def _child(bin_dir: Path, session: str, threads: int | None) -> dict:
    args = [str(bin_dir / "python"), str(HERE), "one", session]
    args += [] if threads is None else [str(threads)]
    out = subprocess.run(args, check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def compare(baseline: Path, sessions: list[str], rounds: int) -> None:
    runs = {"baseline": (baseline, None), "this": (THIS_BIN, None), "this_1": (THIS_BIN, 1)}
    print("| session | run | CPU s (user + sys) | user | sys | wall s | peak RSS MB | "
          "CPU ratio | wall ratio |")
    print("|---|---|---|---|---|---|---|---|---|")
    for session in sessions:
        best: dict[str, dict] = {}
        for _ in range(rounds):
            for name, (bin_dir, threads) in runs.items():
                got = _child(bin_dir, session, threads)
                got["cpu"] = got["user"] + got["sys"]
                keep = best.setdefault(name, got)
                for key in ("cpu", "user", "sys", "wall", "peak_mb"):
                    keep[key] = min(keep[key], got[key])
                if got["sha"] != best["baseline"]["sha"]:
                    raise SystemExit(f"{session}: {name} loaded other arrays than the baseline")
        base = best["baseline"]
        for name, b in best.items():
            print(f"| {Path(session).name} | {name} | {b['cpu']:.2f} | {b['user']:.2f} | "
                  f"{b['sys']:.2f} | {b['wall']:.2f} | {b['peak_mb']:.0f} | "
                  f"{b['cpu'] / base['cpu']:.2f} | {b['wall'] / base['wall']:.2f} |", flush=True)


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "one":
        threads = int(sys.argv[3]) if len(sys.argv) > 3 else None
        print(json.dumps(one(sys.argv[2], threads)))
        return
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--baseline", type=Path, default=Path("/work/main/.venv/bin"))
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("sessions", nargs="+")
    a = p.parse_args()
    compare(a.baseline, a.sessions, a.rounds)


if __name__ == "__main__":
    main()
