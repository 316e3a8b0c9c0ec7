"""Peak memory of a live capture over a long 1 kHz stream (issue 25, item 7: memory that does
not grow over an hour), beside a plain read of the same stream.

    .venv/bin/python bench/capture_memory.py make STREAM.txt --minutes 60 [--rate 1000]
    .venv/bin/python bench/capture_memory.py plain < STREAM.txt
    .venv/bin/python bench/capture_memory.py capture DIR < STREAM.txt
    .venv/bin/python bench/capture_memory.py feed STREAM.txt --speed 60 | ...capture DIR

``make`` writes a synthetic session (poses of 3 s, turns of 2 s) as the lines a device sends
(t,ax,ay,az,gx,gy,gz); ``plain`` reads standard input to its end, the lines counted (the
floor any reader pays); ``capture`` runs the capture's core (imucal.capture.run.capture) on
standard input with targets that are never met, so it reads the whole stream, writes
DIR/session.csv, runs the live detector and the running calibrations, then the final
calibration of the whole file (the once-at-the-end step, whose load of the file is the one
thing that grows with the stream). Each prints one JSON line: its own peak RSS (ru_maxrss),
and for ``capture`` the peak of the loop before the final calibration too (the resident
memory sampled every 20 ms), what the detector kept and the fits made. Fed from a file, the
stream comes as fast as it is read; ``feed`` paces it as a device at ``--speed`` times real
time would (the running fits come as often as over a real capture of that length, compressed).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def make(path: str, minutes: float, rate: float) -> None:
    from imucal.capture.send import frames_of
    from imucal.synth import make_session

    poses = max(2, round((minutes * 60 - 5.0 + 2.0) / 5.0))
    session, _ = make_session(poses=poses, seed=1, acc_rate=rate)
    head, frames = frames_of(session, "lines")
    with open(path, "wb") as f:
        f.write(b"".join(head))
        for i in range(0, len(frames), 100_000):
            f.write(b"".join(frames[i:i + 100_000]))
    print(json.dumps({"samples": len(session.t_acc), "seconds": session.duration}))


def feed(path: str, speed: float) -> None:
    """The stream file to standard output at ``speed`` times real time: a block of about 1 MB
    of lines at a time, once its last sample is due (a device's pace, not a file's)."""
    import time

    out = sys.stdout.buffer
    start = None
    with open(path, "rb") as f:
        out.write(f.readline())  # the header line
        rest = b""
        while True:
            block = f.read(1 << 20)
            if not block:
                break
            block = rest + block
            cut = block.rfind(b"\n") + 1
            block, rest = block[:cut], block[cut:]
            last = block[block.rfind(b"\n", 0, len(block) - 1) + 1:]
            t = float(last.split(b",", 1)[0])
            if start is None:
                start = time.monotonic() - t / speed
            wait = start + t / speed - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            out.write(block)
        out.write(rest)
        out.flush()


def plain() -> None:
    n = 0
    while True:
        b = os.read(0, 1 << 16)
        if not b:
            break
        n += b.count(b"\n")
    print(json.dumps({"lines": n, "max_rss_mb": _rss_mb()}))


class _Sampler:
    """The process's resident memory every 20 ms, its highest so far (VmRSS)."""

    def __init__(self) -> None:
        import threading

        self.peak = 0.0
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        page = os.sysconf("SC_PAGE_SIZE")
        while not self.stop.wait(0.02):
            with open("/proc/self/statm") as f:
                self.peak = max(self.peak, int(f.read().split()[1]) * page / 2**20)

    def done(self) -> float:
        self.stop.set()
        self.thread.join()
        return self.peak


def capture(out: str) -> None:
    import inspect
    import shutil

    import imucal.capture.run as run
    from imucal.capture.detector import StillDetector
    from imucal.capture.sources import FdSource
    from imucal.capture.stop import Targets

    shutil.rmtree(out, ignore_errors=True)
    det = StillDetector()
    # the code before the change (PYTHONPATH to its checkout) takes no detector
    kw = {"detector": det} if "detector" in inspect.signature(run.capture).parameters else {}
    final = run.calibrate_file
    peaks = {}

    def timed_final(*a, **k):  # the once-at-the-end calibration of the whole file
        peaks["loop"] = sampler.done()
        return final(*a, **k)

    import threading

    def patched(path, writer=None):
        # the final calibration is the main thread's call without a writer (the running fits
        # of the code before the change call it too, from their thread, with the writer)
        if writer is None and threading.current_thread() is threading.main_thread():
            return timed_final(path)
        return final(path, writer)

    run.calibrate_file = patched
    sampler = _Sampler()
    r = run.capture(FdSource(0), out, Targets(1e-9, 1e-9, 1e-9), **kw)
    kept = det.retained() if kw else {}
    print(json.dumps({"samples": r.samples, "holds": r.holds, "fits": r.calibrations,
                      "loop_rss_mb": round(peaks.get("loop", float("nan")), 1),
                      "max_rss_mb": round(_rss_mb(), 1), "kept": kept}))
    shutil.rmtree(out, ignore_errors=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    m = sub.add_parser("make")
    m.add_argument("path")
    m.add_argument("--minutes", type=float, default=30.0)
    m.add_argument("--rate", type=float, default=1000.0)
    fd = sub.add_parser("feed")
    fd.add_argument("path")
    fd.add_argument("--speed", type=float, default=60.0)
    sub.add_parser("plain")
    c = sub.add_parser("capture")
    c.add_argument("out")
    args = ap.parse_args()
    if "PYTHONPATH" not in os.environ:  # PYTHONPATH names the checkout to measure
        sys.path.insert(0, str(ROOT))
    if args.cmd == "make":
        make(args.path, args.minutes, args.rate)
    elif args.cmd == "feed":
        feed(args.path, args.speed)
    elif args.cmd == "plain":
        plain()
    else:
        capture(args.out)


if __name__ == "__main__":
    main()
