"""The CPU a live capture takes at 1 kHz (issue 25, item 7: at most a quarter of one core),
beside a plain read of the same stream.

    .venv/bin/python bench/capture.py [--seconds 60] [--rate 1000] [--speed 1]

A synthetic session at ``--rate`` Hz is sent as lines (t,ax,ay,az,gx,gy,gz) into a pipe, paced
at ``--speed`` times real time by a thread of this process, to a consumer process:

1. a plain read: select() and os.read() until the end, the bytes counted (the floor any reader
   of the stream pays);
2. the capture's core (imucal.capture.run.capture) with targets that are never met, so it reads
   the whole stream, writes session.csv, runs the live detector and a calibration of the data
   so far after new holds; the final calibration of the whole file is timed apart and taken
   out;
3. the same with the live view (viewer/live.py) saved to a file, updated at 10 Hz.

Each consumer's CPU (user + sys, every thread) is its own, from inside it; printed per sample
and as the share of one core at the stream's rate. The machine is shared: say the load.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

PLAIN = """
import os, select, sys, time, json
c0 = time.process_time(); n = 0
while True:
    select.select([0], [], [])
    b = os.read(0, 1 << 16)
    if not b:
        break
    n += b.count(b"\\n")
print(json.dumps({"cpu_s": time.process_time() - c0, "lines": n}))
"""

CAPTURE = """
import json, sys, time
from imucal.capture.run import capture, calibrate_file
from imucal.capture.sources import FdSource
from imucal.capture.stop import Targets
import imucal
imucal.calibrate  # the pipeline imported before the clock starts, as a running capture has it
live = None
if len(sys.argv) > 2:  # the live view, saved to a file (as --rrd does)
    from imucal.capture.detector import MIN_HOLD_S
    from viewer.live import LiveView, blueprint
    live = LiveView.new(MIN_HOLD_S)
    live.rec.save(sys.argv[2], default_blueprint=blueprint())
c0 = time.process_time()
r = capture(FdSource(0), sys.argv[1], Targets(1e-9, 1e-9, 1e-9),
            on_batch=None if live is None else live.batch,
            on_status=None if live is None else live.status)
if live is not None:
    live.close()
total = time.process_time() - c0
c1 = time.process_time()
try:
    calibrate_file(r.session)
except imucal.ImucalError:
    pass  # too short to calibrate: the loop's cost is still measured
final = time.process_time() - c1
# VmHWM, not ru_maxrss: Linux carries the forked image's size across exec into ru_maxrss,
# so a child of this benchmark (which holds the whole stream) would report at least its size
hwm = [l for l in open("/proc/self/status") if l.startswith("VmHWM:")][0].split()[1]
print(json.dumps({"cpu_s": total - final, "final_s": final, "lines": r.samples,
                  "fits": r.calibrations, "holds": r.holds, "max_rss_mb": int(hwm) / 1024}))
"""


def _feed(fd: int, t, head: list[bytes], frames: list[bytes], speed: float) -> None:
    from imucal.capture.send import paced

    with os.fdopen(fd, "wb", buffering=0) as out:
        def send(chunk: list[bytes]) -> None:
            out.write(b"".join(chunk))

        send(head)
        paced(t, frames, speed, send)


def _run(code: list[str], stream: tuple, speed: float) -> dict:
    r, w = os.pipe()
    proc = subprocess.Popen([sys.executable, "-c", *code], stdin=r, stdout=subprocess.PIPE,
                            env={**os.environ, "PYTHONPATH": str(ROOT)}, text=True)
    os.close(r)
    feeder = threading.Thread(target=_feed, args=(w, *stream, speed))
    feeder.start()
    out, _ = proc.communicate()
    feeder.join()
    return json.loads(out.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=90.0)
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--speed", type=float, default=1.0)
    args = ap.parse_args()
    sys.path.insert(0, str(ROOT))
    from imucal.synth import make_session

    poses = max(2, round((args.seconds - 5.0 + 2.0) / 5.0))
    session, _ = make_session(poses=poses, seed=1, acc_rate=args.rate)
    n = len(session.t_acc)
    print(f"load average {os.getloadavg()[0]:.2f}; {n} samples at {args.rate:g} Hz "
          f"({session.duration:.0f} s) sent at {args.speed:g}x real time")
    from imucal.capture.send import frames_of

    stream = (session.t_acc, *frames_of(session, "lines"))  # made before any consumer waits
    plain = _run([PLAIN], stream, args.speed)
    with tempfile.TemporaryDirectory() as tmp:
        cap = _run([CAPTURE, str(Path(tmp) / "D")], stream, args.speed)
        view = _run([CAPTURE, str(Path(tmp) / "V"), str(Path(tmp) / "v.rrd")], stream,
                    args.speed)
    assert cap["lines"] == n == plain["lines"] - 1, (cap, plain, n)  # the header line
    for name, res in (("plain read", plain), ("capture", cap), ("+ live view", view)):
        per = res["cpu_s"] / n
        print(f"{name:11s} {res['cpu_s']:6.2f} s CPU, {per * 1e6:6.1f} us/sample, "
              f"{per * args.rate * args.speed * 100:5.1f} % of a core at {args.rate:g} Hz x "
              f"{args.speed:g}")
    print(f"capture: {cap['holds']} holds, {cap['fits']} running calibrations; the final "
          f"calibration of the whole file {cap['final_s']:.2f} s CPU (once, after the stop); "
          f"peak memory {cap['max_rss_mb']:.0f} MB, {view['max_rss_mb']:.0f} MB with the view")


if __name__ == "__main__":
    main()
