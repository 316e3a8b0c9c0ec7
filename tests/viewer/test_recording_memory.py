"""Building a session's recording allocates a chunk of rows at a time, not the session (issue 12:
the recording of a 6-hour 1 kHz session made its calibrated signals whole, 1 GB, besides the
magnitudes, masks and gathers of every sample).

Allocations are measured with tracemalloc (numpy reports its buffers to it; what Rerun encodes
in Rust is not counted, and is bounded by the rows logged), not timed. The limits on rows are
lowered so that the rows kept (bounded whatever the session's length) do not hide what a
signal-sized temporary would cost, and so is the chunk, so that this short session is read in
many of them.
"""

from __future__ import annotations

import tracemalloc

import pytest

import imucal
import imucal.stages.apply as apply
import imucal.stages.detect_stat as detect_stat
import viewer.decimate as D
import viewer.signal_rows as S
from imucal.report import report
from imucal.synth import make_session
from viewer import readback as rb
from viewer.recording import save_recording


@pytest.fixture(scope="module")
def long_result():
    s, _ = make_session(poses=50, seed=3, acc_rate=1000.0, gyro_rate=1000.0)
    return imucal.calibrate(s)


def _peak(f, *args):
    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        before, _ = tracemalloc.get_traced_memory()
        out = f(*args)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return out, peak - before


def test_recording_allocates_well_under_the_session(long_result, tmp_path, monkeypatch):
    r = long_result
    s = r.session
    monkeypatch.setattr(D, "SCREEN_ROWS", 2000)
    monkeypatch.setattr(D, "STILL_ROWS", 4000)
    # Chunks of 8192 rows, the calibration's grid too (Calibration.rows computes whole chunks
    # of its grid).
    monkeypatch.setattr(S, "CHUNK", 1 << 13)
    monkeypatch.setattr(apply, "CHUNK_ROWS", 1 << 13)
    monkeypatch.setattr(detect_stat, "SPAN", 1 << 13)  # the detector's M1, made again
    session = s.acc.nbytes + s.gyro.nbytes + s.t_acc.nbytes + s.t_gyro.nbytes  # 16 MB
    assert len(s.t_acc) > 30 * S.CHUNK

    # The summary's report is the core's (the CLI prints it too); below a million samples a
    # median sample rate copies the clock's steps (imucal.session.MEDIAN_SMALL): counted apart.
    # (The session keeps its rates since calibrate found them: neither copies them now. The
    # recording's own copy used to be its peak, 5.9 MB less the report's 4.0; its peak is now
    # the moment the viewer makes the detector's statistic again, 3.5 MB, which that hid.)
    _, report_peak = _peak(report, r)
    # Once unmeasured first: in a fresh checkout the first call compiles the detector's numba
    # kernel (numerics/window_kernel), whose allocations are the compiler's, not the recording's.
    save_recording(r, tmp_path / "warm.rrd")
    path = tmp_path / "long.rrd"
    rows, peak = _peak(save_recording, r, path)
    assert "calibrated" not in r.__dict__  # the calibrated signals were never made whole
    # Before: 30 MB, 1.8 times the session (the calibrated signals whole, the magnitudes, a
    # gather of every sample); now 3.5 MB: a few chunks, the detector's statistic, the rows
    # kept and the magnitudes' tails the y ranges are read from.
    assert peak - report_peak < 0.25 * session, (peak, report_peak, session)
    # ... and what was written is the whole recording: every entity with its rows.
    ents = rb.entities(path)
    assert all(ents[p] == n for p, n in rows.items())
    assert rows["imu/accelerometer/raw"] <= 2000 and rows["imu/accelerometer/magnitude"] <= 6000
