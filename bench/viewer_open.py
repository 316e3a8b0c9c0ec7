"""How long a recording takes to open in the native viewer, and how much memory, by session length.

Makes synthetic sessions (:func:`imucal.synth.make_session`, 1000 Hz, both sensors) of the
sample's length (3 min), 60 min and 120 min, calibrates them, writes their recordings with the
current ``viewer.recording.save_recording`` and opens each, in turn with the sample
(``sample_data/session.mat``), in a fresh headless native viewer (``rerun --headless``, software
Vulkan, private ``XDG_DATA_HOME``). Per open: the wall time from ``ViewerClient.open`` until the
picture settles (``get_state().loading`` is False, then screenshots one after another until one
equals the next: the viewer goes on filling its store and redrawing the plots for a long while
after "loaded"; the time is the first of the equal pair's), the peak RSS of the viewer's process
tree, sampled every 20 ms over that time, and the time of one more frame once settled.
Figures are minimums over ``--repeat`` rounds (the machine is shared: the minimum is the least
disturbed run) and ratios to the sample's in the same run.

    .venv/bin/python bench/viewer_open.py [--repeat 3] [--cache DIR] [--only 60]

The calibrated sessions are cached (pickled ``Result``) in ``--cache``: only the recordings are
written anew each run, so a change to the logging is measured on the same results.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import pickle
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import psutil

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import imucal  # noqa: E402
from imucal.synth import make_session  # noqa: E402
from viewer.recording import save_recording  # noqa: E402

RERUN = Path(sys.executable).parent / "rerun"
RATE = 1000.0
STILL, MOVE, INIT = 3.0, 2.0, 5.0  # the synth defaults: ~60 % of a session still
CASES = {"sample": None, "3 min": 3.0, "60 min": 60.0, "120 min": 120.0}


@dataclass
class Open:
    seconds: float  # from open until the picture stops changing
    peak_rss_mb: float  # the viewer's process tree, over that time
    frame_seconds: float  # one more frame once settled: how the viewer then responds


def result_for(name: str, cache: Path) -> imucal.Result:
    """The calibrated session of a case, from the cache when there."""
    minutes = CASES[name]
    if minutes is None:
        return imucal.calibrate(imucal.load_session(ROOT / "sample_data" / "session.mat"))
    path = cache / f"result_{int(minutes)}min_{int(RATE)}hz.pkl"
    if path.exists():
        with open(path, "rb") as f:
            return pickle.load(f)
    poses = max(2, round((minutes * 60.0 - INIT + MOVE) / (STILL + MOVE)))
    session, _ = make_session(poses=poses, seed=1, acc_rate=RATE, still=STILL, move=MOVE,
                              init_still=INIT)
    result = imucal.calibrate(session)
    cache.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        pickle.dump(result, f, protocol=pickle.HIGHEST_PROTOCOL)
    return result


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _tree_rss(root: psutil.Process) -> int:
    total = 0
    for p in [root, *root.children(recursive=True)]:
        with contextlib.suppress(psutil.Error):
            total += p.memory_info().rss
    return total


class PeakRss:
    """The peak RSS of a process tree, sampled in a thread."""

    def __init__(self, pid: int, every: float = 0.02):
        self.root, self.every, self.peak = psutil.Process(pid), every, 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            with contextlib.suppress(psutil.Error):
                self.peak = max(self.peak, _tree_rss(self.root))
            time.sleep(self.every)

    def __enter__(self) -> PeakRss:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()
        self.peak = max(self.peak, _tree_rss(self.root))


def open_in_viewer(rrd: Path, tmp: Path, timeout: float = 300.0) -> Open:
    """Open ``rrd`` in a fresh headless viewer; time until loaded and drawn, peak RSS."""
    from rerun.experimental import ViewerClient

    port = _free_port()
    env = dict(os.environ, XDG_DATA_HOME=str(tmp / "xdg"), RUST_LOG="warn")
    log = open(tmp / "viewer.log", "w")  # noqa: SIM115
    proc = subprocess.Popen([str(RERUN), "--headless", "--bind", "127.0.0.1", "--port",
                             str(port), "--window-size", "1600x1000", "--hide-welcome-screen"],
                            env=env, stdout=subprocess.DEVNULL, stderr=log,
                            start_new_session=True)
    try:
        client = _connect(ViewerClient, port, proc)
        client.take_screenshot()  # the empty viewer has drawn once: its start is not counted
        with PeakRss(proc.pid) as rss:
            t0 = time.perf_counter()
            client.open([str(rrd)])  # returns early: the file goes on loading in the viewer
            deadline = t0 + timeout
            while client.get_state().loading:
                _check(deadline, rrd)
                time.sleep(0.02)
            # The store fills and the plots redraw for a while after "loaded": the picture has
            # settled when a screenshot equals the next one; it settled at the first of them.
            last, at = _picture(client), time.perf_counter()
            while True:
                _check(deadline, rrd)
                shot = _picture(client)
                if _same(shot, last):
                    break
                last, at = shot, time.perf_counter()
            seconds = at - t0
        f0 = time.perf_counter()
        _picture(client)
        return Open(seconds, rss.peak / 2**20, time.perf_counter() - f0)
    finally:
        _stop(proc)
        log.close()


def _check(deadline: float, rrd: Path) -> None:
    if time.perf_counter() > deadline:
        raise TimeoutError(f"{rrd}: the viewer did not settle in time")


def _picture(client) -> np.ndarray:
    from PIL import Image  # a dependency of rerun-sdk

    try:
        png = client.take_screenshot()
    except TimeoutError:  # a frame that takes longer than the client waits: not settled
        return np.zeros((0, 0, 3), np.int16)
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.int16)


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal but for a few pixels (text antialiasing may flicker)."""
    return a.shape == b.shape and a.size > 0 and int((np.abs(a - b).max(axis=-1) > 24).sum()) <= 20


def _connect(client_cls, port: int, proc: subprocess.Popen):
    deadline = time.monotonic() + 60
    while True:
        if proc.poll() is not None:
            raise RuntimeError(f"the headless viewer exited ({proc.returncode})")
        try:
            client = client_cls.connect(f"rerun+http://127.0.0.1:{port}/proxy")
            client.get_state()
            return client
        except Exception:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.3)


def _stop(proc: subprocess.Popen) -> None:
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGTERM)
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--cache", type=Path,
                    default=Path(tempfile.gettempdir()) / "imucal-bench-viewer")
    ap.add_argument("--only", nargs="*", default=None, help="cases besides the sample, e.g. 60")
    ap.add_argument("--still-rows", type=int, default=None,
                    help="measure another viewer.decimate.STILL_ROWS (0: every still sample)")
    args = ap.parse_args()
    if args.still_rows is not None:
        import viewer.decimate

        viewer.decimate.STILL_ROWS = args.still_rows or 2**62
    names = [n for n in CASES if n == "sample" or args.only is None
             or n.split()[0] in args.only]
    work = Path(tempfile.mkdtemp(prefix="viewer_open_"))
    info: dict[str, tuple[int, int, int, float]] = {}
    for name in names:
        result = result_for(name, args.cache)
        rrd = work / f"{name.replace(' ', '_')}.rrd"
        t0 = time.perf_counter()
        rows = save_recording(result, rrd)
        write = time.perf_counter() - t0
        info[name] = (len(result.session.t_acc), sum(rows.values()), rrd.stat().st_size, write)
        del result
        print(f"{name}: {info[name][0]} samples, {info[name][1]} rows, "
              f"{info[name][2] / 1e6:.1f} MB, written in {write:.1f} s", flush=True)
    opens: dict[str, list[Open]] = {n: [] for n in names}
    for r in range(args.repeat):
        for name in names:
            o = open_in_viewer(work / f"{name.replace(' ', '_')}.rrd", work)
            opens[name].append(o)
            print(f"round {r + 1} {name}: {o.seconds:.2f} s, {o.peak_rss_mb:.0f} MB, "
                  f"frame {o.frame_seconds:.2f} s", flush=True)
    best = {n: (min(o.seconds for o in v), min(o.peak_rss_mb for o in v),
                min(o.frame_seconds for o in v)) for n, v in opens.items()}
    s0, m0, _ = best["sample"]
    print(f"\nminimum of {args.repeat} opens; ratios to the sample's in this run\n")
    print("| recording | samples/sensor | rows | .rrd MB | write s | open s | x sample "
          "| peak RSS MB | x sample | frame s |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for n in names:
        samples, rows, size, write = info[n]
        s, m, fr = best[n]
        print(f"| {n} | {samples:,} | {rows:,} | {size / 1e6:.1f} | {write:.1f} | {s:.2f} "
              f"| {s / s0:.2f} | {m:.0f} | {m / m0:.2f} | {fr:.2f} |")
    for f in work.iterdir():
        if f.is_file():
            f.unlink()


if __name__ == "__main__":
    main()
