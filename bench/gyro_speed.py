"""The gyroscope stage and the whole ``imucal calibrate``, this checkout against a baseline
install, measured alternately in the same run (issue 12; the machine is shared, so only ratios
measured side by side mean much).

    .venv/bin/python bench/gyro_speed.py --baseline /work/main/.venv/bin --rounds 3 \\
        /tmp/mn_n60.mat /tmp/mn_n360.mat

For each session and round, the baseline's then this checkout's:

* ``imucal calibrate SESSION -o calib.json`` as a child process: wall time, CPU time (user +
  sys) and max RSS from ``os.wait4``;
* the gyroscope stage alone, in a child process (``gyro_speed.py stage SESSION``): the
  pipeline runs up to ``calibrate_gyroscope`` (wrapped to capture its arguments and stop), then
  the stage is timed by itself (wall, and CPU from ``time.process_time``).

The minimum over the rounds is reported, with this checkout's figure over the baseline's.
``gyro_speed.py passes SESSION`` (run by either install's python) prints the CPU seconds of
each kind of pass over the turns instead.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve()
THIS_BIN = Path(sys.executable).parent


class _Captured(Exception):
    pass


def stage(session: str) -> dict:
    """The gyroscope stage of ``session`` timed alone (run by the install being measured)."""
    import imucal.pipeline as pipeline
    from imucal.io.load import load_session

    got: dict = {}

    def capture(*args, **kwargs):
        got["args"], got["kwargs"] = args, kwargs
        raise _Captured

    run = pipeline.calibrate_gyroscope
    pipeline.calibrate_gyroscope = capture
    try:
        pipeline.calibrate(load_session(session))
    except _Captured:
        pass
    finally:
        pipeline.calibrate_gyroscope = run
    t0, c0 = time.perf_counter(), time.process_time()
    run(*got["args"], **got["kwargs"])
    return {"wall": time.perf_counter() - t0, "cpu": time.process_time() - c0}


def passes(session: str, repeat: int = 2) -> dict:
    """CPU seconds of each kind of pass over the turns of ``session`` (mean of ``repeat``),
    under a model near the identity (run by the install being measured)."""
    import numpy as np

    import imucal.pipeline as pipeline
    from imucal.io.load import load_session
    from imucal.models import SensorModel
    from imucal.stages.gyro_transitions import Transitions

    got: dict = {}

    def capture(*args, **kwargs):
        got["args"] = args
        raise _Captured

    pipeline.calibrate_gyroscope = capture
    try:
        pipeline.calibrate(load_session(session))
    except _Captured:
        pass
    w, t, blocks = got["args"][:3]
    tr = Transitions(w, t, blocks)
    m = SensorModel(T=np.eye(3), K=np.full(3, 1.01), b=np.array([0.01, 0.0, -0.01]))
    M, b = np.tile(m.matrix, (len(tr), 1, 1)), np.tile(m.b, (len(tr), 1))
    runs = {"sensitivity": lambda: tr.layout.sensitivity(tr.rates, m.matrix, m.b),
            "integration": lambda: tr.layout.integrate(tr.rates, [(m.matrix, m.b)]),
            "held_out": lambda: tr.rotations_each(M, b),
            "max_step": lambda: tr.max_step_angle(m)}
    out = dict.fromkeys(runs, 0.0)
    for _ in range(repeat):
        for name, run in runs.items():
            c0 = time.process_time()
            run()
            out[name] += (time.process_time() - c0) / repeat
    return out


def _child(cmd: list[str]) -> dict:
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    out = proc.stdout.read()
    _, status, usage = os.wait4(proc.pid, 0)
    if status != 0:
        raise RuntimeError(f"{cmd} failed ({status})")
    return {"wall": time.perf_counter() - t0, "cpu": usage.ru_utime + usage.ru_stime,
            "rss_mb": usage.ru_maxrss / 1024, "out": out}


def measure(bin_dir: Path, session: str, tmp: str) -> dict:
    whole = _child([str(bin_dir / "imucal"), "calibrate", session, "-o", f"{tmp}/calib.json"])
    alone = json.loads(_child([str(bin_dir / "python"), str(HERE), "stage", session])["out"])
    return {"whole_wall": whole["wall"], "whole_cpu": whole["cpu"], "whole_rss_mb":
            whole["rss_mb"], "gyro_wall": alone["wall"], "gyro_cpu": alone["cpu"]}


def compare(baseline: Path, sessions: list[str], rounds: int) -> None:
    keys = ["gyro_wall", "gyro_cpu", "whole_wall", "whole_cpu", "whole_rss_mb"]
    print("| session | | " + " | ".join(keys) + " |")
    print("|---|---|" + "---:|" * len(keys))
    for session in sessions:
        runs: dict[str, list[dict]] = {"baseline": [], "this": []}
        with tempfile.TemporaryDirectory() as tmp:
            for _ in range(rounds):
                runs["baseline"].append(measure(baseline, session, tmp))
                runs["this"].append(measure(THIS_BIN, session, tmp))
        best = {who: {k: min(r[k] for r in rs) for k in keys} for who, rs in runs.items()}
        for who in ("baseline", "this"):
            print(f"| {Path(session).name} | {who} | "
                  + " | ".join(f"{best[who][k]:.2f}" for k in keys) + " |")
        print(f"| {Path(session).name} | ratio | "
              + " | ".join(f"{best['this'][k] / best['baseline'][k]:.3f}" for k in keys) + " |")
        sys.stdout.flush()


def main() -> None:
    if len(sys.argv) == 3 and sys.argv[1] in ("stage", "passes"):
        print(json.dumps({"stage": stage, "passes": passes}[sys.argv[1]](sys.argv[2])))
        return
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sessions", nargs="+")
    ap.add_argument("--baseline", type=Path, required=True, help="bin/ of the baseline venv")
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    compare(args.baseline, args.sessions, args.rounds)


if __name__ == "__main__":
    main()
