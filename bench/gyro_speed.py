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
``gyro_speed.py passes SESSION [OUT.npz]`` (run by either install's python) prints the CPU
seconds of each kind of pass over the turns instead (and writes their outputs, to compare).
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


def passes(session: str, repeat: int = 2, save: str | None = None) -> dict:
    """CPU seconds of each kind of pass over the turns of ``session`` (mean of ``repeat``,
    after one round untimed: numba's import and cache load, page faults), under a model near
    the identity (run by the install being measured: main's numpy layout before 2026-11-23 or
    the compiled kernels). With ``save``, each pass's output is written there (.npz) to
    compare the two installs' numbers."""
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
    scales = np.exp(np.linspace(np.log(0.5), np.log(4.0), 13))  # the scale search's grid
    if hasattr(tr, "turns"):  # the compiled kernels
        def sensitivity():
            return tuple(tr.turns.sensitivity(m.matrix, m.b))

        def scale_grid():
            return tr.rotations_many([SensorModel(np.eye(3), np.full(3, s), m.b)
                                      for s in scales])
    else:  # the numpy layout
        def sensitivity():
            return tuple(tr.layout.sensitivity(tr.rates, m.matrix, m.b))[:2]

        def scale_grid():
            iso = tr.isotropic(m.b)
            return np.stack([iso(s) for s in scales])
    runs = {"sensitivity": sensitivity,
            "integration": lambda: tr.rotations_many([m]),
            "held_out": lambda: tr.rotations_each(M, b),
            "max_step": lambda: tr.max_step_angle(m),
            "scale_grid_13": scale_grid}
    results = {name: run() for name, run in runs.items()}
    out = dict.fromkeys(runs, 0.0)
    for _ in range(repeat):
        for name, run in runs.items():
            c0 = time.process_time()
            run()
            out[name] += (time.process_time() - c0) / repeat
    if save:
        q, S = results.pop("sensitivity")
        np.savez(save, sensitivity_q=q, sensitivity_S=S,
                 **{k: np.asarray(v) for k, v in results.items()})
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
    if len(sys.argv) == 3 and sys.argv[1] == "stage":
        print(json.dumps(stage(sys.argv[2])))
        return
    if len(sys.argv) in (3, 4) and sys.argv[1] == "passes":
        print(json.dumps(passes(sys.argv[2], save=sys.argv[3] if len(sys.argv) == 4 else None)))
        return
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sessions", nargs="+")
    ap.add_argument("--baseline", type=Path, required=True, help="bin/ of the baseline venv")
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    compare(args.baseline, args.sessions, args.rounds)


if __name__ == "__main__":
    main()
