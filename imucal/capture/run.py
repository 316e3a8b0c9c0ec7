"""The capture loop (method.md §13): read, parse, write, detect; after each new hold,
calibrate what the detector keeps (imucal.capture.running: the method's fits on the kept holds
and turns, in a worker thread so that reading goes on); stop when the targets are met, when a
spec can no longer be met, at ``until`` seconds, at the end of the stream or on Ctrl-C; then
calibrate the whole session file once with the full method.

The loop itself only moves batches: the parsing, the detector and the writer work on whole
batches with numpy, and nothing but the session file grows with the stream (the detector keeps
a bounded number of holds and turns, each turn in bounded rows).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from imucal.capture.byte_source import Source
from imucal.capture.detector import MIN_HOLD_S, DetectorState, StillDetector, guide_line
from imucal.capture.lines import Batch, LineParser
from imucal.capture.running import Retained, fit_retained, rate_per_unit, retained
from imucal.capture.stop import Progress, Targets, progress, running_progress
from imucal.capture.writer import SESSION_NAME, SessionWriter
from imucal.errors import ImucalError, plural
from imucal.stages.guide import ADVISED_HOLD_S, ORIENTATIONS_NEEDED
from imucal.stages.gyro import MAX_STEP_DEG

NO_DATA_S = 5.0  # no valid sample this long after the start: say what came and what to check
READ_S = 0.1  # the longest one read waits: the flush, the timer and --until stay on time
TICK_S = 1.0  # a status line at least this often
# The running fits take at most this share of the time: after a fit that took d seconds the
# next waits (1 / FIT_SHARE - 1) d (issue 25: a quarter of a core in all). A fit's cost is
# bounded by the holds and turns kept, not by the stream's length.
FIT_SHARE = 0.2


@dataclass
class CaptureReport:
    session: Path  # DIR/session.csv
    samples: int  # valid samples written
    garbled: int  # lines counted and skipped
    stopped: str  # "targets met", "out of the spec", "time limit", "end of stream",
    #               "interrupted"
    progress: Progress | None  # the last running calibration's, None if none ran
    calibrations: int  # running calibrations done
    holds: int
    orientations: int
    duration_s: float
    write_error: str | None = None  # the OS error that stopped the writing (a full disk)
    final: Progress | None = None  # the whole session file's calibration against the targets
    final_error: str | None = None  # why the whole session file does not calibrate

    @property
    def passed(self) -> bool:
        """The factory's pass: the whole session's calibration meets the targets."""
        return self.final is not None and self.final.met

    def lines(self) -> list[str]:
        out = [f"capture         {self.samples} samples in {self.duration_s:.1f} s, "
               f"{plural(self.garbled, 'garbled line')} skipped; "
               f"{plural(self.holds, 'hold')}, {plural(self.orientations, 'pose')}; "
               f"stopped: {self.stopped}",
               f"running fits    {self.calibrations}"
               + (f"; last {self.progress.text()}" if self.progress is not None else ""),
               "whole session   " + (self.final.text() if self.final is not None else
                                     f"does not calibrate: {self.final_error}")]
        if self.write_error:
            out.append(f"warning: writing stopped: {self.write_error}; the session holds "
                       f"the samples before it")
        return out


def calibrate_file(path: Path, writer: SessionWriter | None = None):
    """The full method on the session file (the lock held while it is read: whole rows)."""
    import imucal

    if writer is None:
        session = imucal.load_session(path)
    else:
        with writer.lock:
            session = imucal.load_session(path)
    return imucal.calibrate(session)


def capture(source: Source, out: str | Path, goal: Targets, *, columns: str | None = None,
            rate: float | None = None, until: float | None = None,
            on_status: Callable[[dict], None] | None = None,
            on_batch: Callable[[Batch, DetectorState], None] | None = None,
            spec=None, no_data_s: float = NO_DATA_S, detector: StillDetector | None = None
            ) -> CaptureReport:
    """Capture ``source`` into ``out``/session.csv until the calibration meets ``goal`` (see the
    module's docstring); ``on_status`` gets the guide as a dict (:func:`status`), ``on_batch``
    each batch of samples with the detector's state after it (the live view), ``spec`` the
    limits the unit must be within (:class:`imucal.capture.stop.SpecCheck`);
    ``detector`` the incremental detector to use (a test reads what it keeps)."""
    out = Path(out)
    if (out / SESSION_NAME).exists():
        raise ImucalError("a capture is already there; give another --out directory",
                          source=str(out / SESSION_NAME))
    parser = LineParser(source.describe, columns=columns, rate=rate)
    det = StillDetector() if detector is None else detector
    writer: SessionWriter | None = None
    pool = ThreadPoolExecutor(1, thread_name_prefix="imucal-capture-fit")
    future: Future | None = None
    want_fit = False
    last: Progress | None = None
    fits = 0
    per_unit = float("nan")  # rad/s per raw gyroscope unit, once known
    st = DetectorState("waiting", 0.0, 0, 0, 0.0, "any axis up")
    start = time.monotonic()
    last_tick = start
    fit_started = next_fit = start
    stopped = "end of stream"

    def emit(event: str) -> None:
        if on_status is not None:
            on_status(status(event, time.monotonic() - start, st, parser, last,
                             getattr(source, "garbled", 0), per_unit, det.rate))

    try:
        while True:
            now = time.monotonic()
            if until is not None and now - start >= until:
                stopped = "time limit"
                break
            data = source.read(READ_S)
            if data is None:
                break
            batch = parser.feed(data) if data else None
            if parser.layout is not None and writer is None:
                writer = SessionWriter(out, parser.header)
            if batch is not None:
                writer.add(batch.text)
                state = st.state
                st = det.feed(batch.t, batch.acc, batch.gyro)
                if per_unit != per_unit and st.new_holds and det.turns:  # NaN: not yet
                    per_unit = rate_per_unit(_retained(det, parser))
                if on_batch is not None:
                    st.turn = turn_figures(st, per_unit, det.rate)
                    on_batch(batch, st)
                if st.new_holds:
                    want_fit = True
                    emit("hold")
                elif st.state != state:
                    emit("state")
            now = time.monotonic()
            if parser.valid == 0 and now - start >= no_data_s:
                raise _no_data(source, parser, no_data_s)
            if writer is not None and writer.due(now):
                writer.flush(wait=False)
            if future is not None and future.done():
                last, unit, future = *_fitted(future), None
                per_unit = unit if unit == unit else per_unit
                if fits:  # the first fit also loads the method's code: not its pace
                    next_fit = now + (now - fit_started) * (1.0 / FIT_SHARE - 1.0)
                fits += 1
                emit("calibration")
                if last is not None and last.met:
                    stopped = "targets met"
                    break
                if last is not None and last.failed:
                    stopped = "out of the spec: " + "; ".join(last.lost)
                    break
            if (want_fit and future is None and st.orientations >= ORIENTATIONS_NEEDED
                    and now >= next_fit):
                fit_started = now
                future = pool.submit(_fit_so_far, _retained(det, parser), goal, spec)
                want_fit = False
            if now - last_tick >= TICK_S:
                last_tick = now
                emit("tick")
    except KeyboardInterrupt:
        stopped = "interrupted"
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
        if writer is not None:
            writer.close()
            if parser.valid == 0:  # a header and no sample: nothing to keep, nothing in the way
                writer.path.unlink(missing_ok=True)
        source.close()
    if parser.valid == 0:
        raise _no_data(source, parser, time.monotonic() - start)
    duration = time.monotonic() - start
    final_error = None
    try:  # the pass/fail is the whole file's, not the last running fit's
        final = progress(calibrate_file(writer.path), goal, spec)
    except ImucalError as e:
        final, final_error = None, str(e)
    last = final if final is not None else last
    emit("stop")
    return CaptureReport(session=writer.path, samples=writer.rows,
                         garbled=parser.garbled + getattr(source, "garbled", 0),
                         stopped=stopped, progress=last, calibrations=fits,
                         holds=st.holds, orientations=st.orientations,
                         duration_s=duration, write_error=writer.error, final=final,
                         final_error=final_error)


def _retained(det: StillDetector, parser: LineParser) -> Retained:
    lay = parser.layout
    return retained(det, lay.names, lay.acc, lay.gyro)


def _fit_so_far(kept: Retained, goal: Targets, spec) -> tuple[Progress, float]:
    fit = fit_retained(kept)
    return running_progress(fit, goal, spec), fit.per_unit


def _fitted(future: Future) -> tuple[Progress | None, float]:
    """A running calibration's progress and the gyroscope's rad/s per raw unit; None (and
    NaN) when the data so far do not calibrate yet."""
    try:
        return future.result()
    except ImucalError:
        return None, float("nan")


def _no_data(source: Source, parser: LineParser, seconds: float) -> ImucalError:
    return ImucalError(f"no valid sample in {seconds:.0f} s: received {parser.said()}; check "
                       f"{source.hint}", source=source.describe)


def status(event: str, elapsed: float, st: DetectorState, parser: LineParser,
           last: Progress | None, garbled_frames: int = 0, per_unit: float = float("nan"),
           rate_hz: float | None = None) -> dict:
    """One status object (``--json-status`` prints it as a line of JSON); ``garbled_frames``
    what the source itself skipped (bytes that form no MAVLink message); ``per_unit`` the
    gyroscope's rad/s per raw unit (NaN until known), ``rate_hz`` the sample rate."""
    turn = turn_figures(st, per_unit, rate_hz)
    return {"event": event, "elapsed_s": round(elapsed, 3), "state": st.state,
            "hold_s": round(st.hold_s, 2), "hold_min_s": MIN_HOLD_S,
            "hold_advised_s": ADVISED_HOLD_S, **turn,
            "holds": st.holds, "orientations": st.orientations,
            "orientations_needed": ORIENTATIONS_NEEDED, "coverage": round(st.coverage, 3),
            "next_pose": st.next_pose, "samples": parser.valid,
            "garbled": parser.garbled + garbled_frames,
            "calibration": None if last is None else
            {"verdict": last.level, "worst": last.worst, "ratio": round(last.ratio, 3),
             "met": last.met, "broken": list(last.broken), "lost": list(last.lost)},
            "guide": guide_line(st, turn)}


def turn_figures(st: DetectorState, per_unit: float, rate_hz: float | None) -> dict:
    """The turn's rate now and its peak since the last hold, in deg/s, against the method's
    limit (the rotation M5's RK4 integration carries per sample, ``MAX_STEP_DEG`` times the
    sample rate); None where not known (no gyroscope, the unit or the rate not known yet)."""
    def dps(x: float) -> float | None:
        return round(float(np.degrees(x * per_unit)), 1) if per_unit == per_unit else None

    limit = None if not rate_hz else round(MAX_STEP_DEG * rate_hz, 1)
    return {"rate_dps": dps(st.rate), "turn_peak_dps": dps(st.turn_peak),
            "rate_limit_dps": limit}
