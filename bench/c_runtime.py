"""The C runtime (``imucal export --to c-runtime``): nanoseconds per sample and the bytes of its
state, on this machine.

    .venv/bin/python bench/c_runtime.py [--minutes 10] [--repeat 20] [--activity walk]
                                        [--max-rate 200] [--cflags "-O2"]

Ten minutes of synthetic everyday use at 100 Hz (imucal.inuse.everyday, a drifted gyroscope
bias: moments found and the bias refreshed as on a device) run ``--repeat`` times through the
runtime by its host driver (each pass from ``imucal_rt_init``); the time is the driver's
CLOCK_MONOTONIC over all passes divided by the samples, so it includes the driver's loop and
its store of each calibrated sample, not the reading of the file. Run it three times and take
the lowest: the machine is shared. The state's bytes are the compiler's ``sizeof``.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from imucal.inuse.everyday import Drift, make_everyday
from imucal.io.exports import c_runtime
from imucal.io.exports.common import ExportInput
from imucal.stages.apply import Calibration, SegmentModels


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--repeat", type=int, default=20)
    ap.add_argument("--activity", default="walk")
    ap.add_argument("--max-rate", type=int, default=c_runtime.DEFAULT_MAX_RATE_HZ)
    ap.add_argument("--cflags", default="-O2")
    args = ap.parse_args()
    cc = shutil.which("cc")
    if cc is None:
        raise SystemExit("no C compiler (cc)")
    session, truth = make_everyday(args.activity, minutes=args.minutes, seed=0,
                                   drift=Drift(gyro_bias=np.radians([0.3, -0.25, 0.2])))
    cal = Calibration(segments=(SegmentModels(0.0, 0.0, truth.stored_acc, truth.stored_gyro),),
                      acc_unit_raw="g", acc_unit="g", g=1.0, gyro_unit_raw="rad/s")
    inp = ExportInput(path=Path("calib.json"), calibration=cal, source={},
                      noise={"accelerometer": {"white_noise_density": [truth.acc_noise / 10]
                                               * 3}})
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        for path, text in c_runtime.export(inp, d, None).files:
            path.write_text(text)
        (d / "driver.c").write_text(c_runtime.DRIVER_C)
        subprocess.run([cc, "-std=c99", *args.cflags.split(),
                        f"-DIMUCAL_RT_MAX_RATE_HZ={args.max_rate}", "-o", str(d / "driver"),
                        str(d / "driver.c"), str(d / c_runtime.SOURCE), "-lm"], check=True)
        np.column_stack([session.acc, session.gyro]).astype(np.float32).tofile(d / "in.bin")
        out = subprocess.run([str(d / "driver"), "100", str(d / "in.bin"), str(d / "out.bin"),
                              str(args.repeat)], capture_output=True, text=True,
                             check=True).stdout.splitlines()
    values = {line.split()[0]: line.split()[1:] for line in out}
    moments = sum(line.startswith("moment") for line in out)
    print(f"samples        {len(session.acc)} x {args.repeat} passes ({args.activity}, "
          f"{args.minutes:g} min at 100 Hz, {moments} still moments a pass)")
    print(f"ns per sample  {float(values['ns_per_sample'][0]):.1f} (cc {args.cflags})")
    print(f"state bytes    {values['sizeof'][0]} (IMUCAL_RT_MAX_RATE_HZ = {args.max_rate})")


if __name__ == "__main__":
    main()
