"""The C runtime (``imucal export --to c-runtime``): nanoseconds per sample and the bytes of its
state on this machine, against the gyroscope-only runtime it grew from, measured in the same run.

    .venv/bin/python bench/c_runtime.py [--minutes 10] [--repeat 20] [--activity walk]
                                        [--max-rate 200] [--cflags "-O2"] [--baseline REV]

Ten minutes of synthetic everyday use at 100 Hz (imucal.inuse.everyday: the gyroscope's bias and
the accelerometer's biases and scales drifted, so moments are found and both refreshed as on a
device) run ``--repeat`` times through the runtime by its host driver (each pass from
``imucal_rt_init``); the time is the driver's CLOCK_MONOTONIC over all passes divided by the
samples, so it includes the driver's loop and its store of each calibrated sample, not the
reading of the file. The baseline is the runtime as it was at git revision ``--baseline`` (the
gyroscope's refresh only: its module is read with ``git show`` and run as it was), compiled and
run alike on the same samples; its driver stores 9 floats a sample where today's stores 15.
Passes alternate between the two (so a neighbour's load hits both); each one's lowest is kept.
The state's bytes are the compiler's ``sizeof``.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import types
from pathlib import Path

import numpy as np

from imucal.inuse.everyday import Drift, make_everyday
from imucal.io.exports import c_runtime
from imucal.io.exports.common import ExportInput
from imucal.stages.apply import Calibration, SegmentModels

ROOT = Path(__file__).resolve().parents[1]
BASELINE = "a26b34b"  # the last revision whose runtime refreshed only the gyroscope's bias


def old_module(rev: str) -> types.ModuleType:
    """imucal/io/exports/c_runtime.py as it was at ``rev``."""
    text = subprocess.run(["git", "-C", str(ROOT), "show", f"{rev}:imucal/io/exports/c_runtime.py"],
                          capture_output=True, text=True, check=True).stdout
    mod = types.ModuleType(f"c_runtime_at_{rev}")
    mod.__dict__["__package__"] = "imucal.io.exports"
    sys.modules[mod.__name__] = mod  # dataclasses and annotations look it up
    exec(compile(text, f"{rev}:c_runtime.py", "exec"), mod.__dict__)
    return mod


def build(module, inp: ExportInput, d: Path, cc: str, flags: list[str]) -> Path:
    d.mkdir()
    for path, text in module.export(inp, d, None).files:
        path.write_text(text)
    (d / "driver.c").write_text(module.DRIVER_C)
    subprocess.run([cc, "-std=c99", *flags, "-o", str(d / "driver"), str(d / "driver.c"),
                    str(d / module.SOURCE), "-lm"], check=True)
    return d / "driver"


def run(exe: Path, d: Path, repeat: int) -> dict[str, list[str]]:
    out = subprocess.run([str(exe), "100", str(d / "in.bin"), str(exe.parent / "out.bin"),
                          str(repeat)], capture_output=True, text=True, check=True).stdout
    lines = out.splitlines()
    values = {line.split()[0]: line.split()[1:] for line in lines}
    values["moments"] = [str(sum(line.startswith("moment") for line in lines))]
    return values


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--repeat", type=int, default=20)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--activity", default="walk")
    ap.add_argument("--max-rate", type=int, default=c_runtime.DEFAULT_MAX_RATE_HZ)
    ap.add_argument("--cflags", default="-O2")
    ap.add_argument("--baseline", default=BASELINE)
    args = ap.parse_args()
    cc = shutil.which("cc")
    if cc is None:
        raise SystemExit("no C compiler (cc)")
    session, truth = make_everyday(args.activity, minutes=args.minutes, seed=0, drift=Drift(
        gyro_bias=np.radians([0.3, -0.25, 0.2]), acc_bias=np.array([0.006, -0.004, 0.008]),
        acc_scale=np.array([0.003, 0.0, -0.002])))
    cal = Calibration(segments=(SegmentModels(0.0, 0.0, truth.stored_acc, truth.stored_gyro),),
                      acc_unit_raw="g", acc_unit="g", g=1.0, gyro_unit_raw="rad/s")
    inp = ExportInput(path=Path("calib.json"), calibration=cal, source={},
                      noise={"accelerometer": {"white_noise_density": [truth.acc_noise / 10]
                                               * 3}},
                      quality={"static_norm_rms_mg": {"cross_validated": 0.3}})
    flags = [*args.cflags.split(), f"-DIMUCAL_RT_MAX_RATE_HZ={args.max_rate}"]
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        np.column_stack([session.acc, session.gyro]).astype(np.float32).tofile(d / "in.bin")
        exes = {"today": build(c_runtime, inp, d / "today", cc, flags),
                "baseline": build(old_module(args.baseline), inp, d / "baseline", cc, flags)}
        best: dict[str, dict] = {}
        for _ in range(args.rounds):
            for name, exe in exes.items():
                got = run(exe, d, args.repeat)
                ns = float(got["ns_per_sample"][0])
                if name not in best or ns < float(best[name]["ns_per_sample"][0]):
                    best[name] = got
    now, base = best["today"], best["baseline"]
    ns, ns0 = float(now["ns_per_sample"][0]), float(base["ns_per_sample"][0])
    moments = int(now["moments"][0])
    n = len(session.acc)
    print(f"samples        {n} x {args.repeat} passes x {args.rounds} rounds ({args.activity}, "
          f"{args.minutes:g} min at 100 Hz, {moments} still moments a pass; cc {args.cflags})")
    print(f"ns per sample  {ns:.1f} today, {ns0:.1f} gyroscope-only ({args.baseline}): "
          f"x{ns / ns0:.2f}")
    if moments:
        print(f"per moment     {(ns - ns0) * n / moments / 1e3:.1f} us more (the "
              "accelerometer's refit, spread over the samples above)")
    b, b0 = int(now["sizeof"][0]), int(base["sizeof"][0])
    print(f"state bytes    {b} today, {b0} gyroscope-only: x{b / b0:.2f} "
          f"(IMUCAL_RT_MAX_RATE_HZ = {args.max_rate}, IMUCAL_RT_MAX_MOMENTS = "
          f"{c_runtime.DEFAULT_MAX_MOMENTS})")


if __name__ == "__main__":
    main()
