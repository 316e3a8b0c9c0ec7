"""How many rows a signal gets (viewer/decimate.py), read back from the .rrd.

Small sessions (100 Hz) with the limits lowered stand in for long ones: the rule is the same,
the sizes are the test's. The timing is in bench/viewer_open.py, never here.
"""

from __future__ import annotations

import numpy as np
import pytest

import imucal
import viewer.decimate as D
from imucal.numerics.windows import runs_of_true
from imucal.synth import make_session
from viewer import paths as P
from viewer import readback as rb
from viewer.recording import save_recording
from viewer.stream import magnitudes_for_display

SCREEN = 600  # SCREEN_ROWS for these tests


@pytest.fixture(scope="module")
def results():
    """Two sessions, one about twice the other's length (gyroscope at another rate)."""
    out = {}
    for poses in (30, 60):
        s, _ = make_session(poses=poses, seed=poses, acc_rate=100.0, gyro_rate=140.0)
        out[poses] = imucal.calibrate(s)
    return out


def _save(result, path, monkeypatch, still_rows: int):
    monkeypatch.setattr(D, "SCREEN_ROWS", SCREEN)
    monkeypatch.setattr(D, "STILL_ROWS", still_rows)
    rows = save_recording(result, path)
    return rows


def _in_runs(t: np.ndarray, t_sig: np.ndarray, runs: np.ndarray) -> np.ndarray:
    """Index of the run (by the signal's sample times) that each time lies in, -1 if none."""
    first, last = t_sig[runs[:, 0]], t_sig[runs[:, 1] - 1]
    k = np.searchsorted(first, t + 1e-9, side="right") - 1
    ok = (k >= 0) & (t <= last[np.maximum(k, 0)] + 1e-9)
    return np.where(ok, k, -1)


def _expected(x: np.ndarray, runs: np.ndarray, size: int) -> np.ndarray:
    """Reference min/max rows, bucket by bucket (a plain loop: the test's own arithmetic)."""
    rows = []
    for a, b in runs:
        for s in range(a, b, size):
            chunk = x[s:min(s + size, b)]
            if size == 1:
                rows.append(chunk[0])
                continue
            i_min, i_max = chunk.argmin(axis=0), chunk.argmax(axis=0)
            lo, hi = chunk.min(axis=0), chunk.max(axis=0)
            rows.append(np.where(i_min <= i_max, lo, hi))
            rows.append(np.where(i_min <= i_max, hi, lo))
    return np.array(rows)


def _check_runs(t, v, t_sig, x, runs, size):
    """Rows read back inside ``runs`` are exactly the per-bucket min/max (or the samples)."""
    k = _in_runs(t, t_sig, runs)
    got = v[k >= 0]
    np.testing.assert_array_equal(got, _expected(x, runs, size))
    return k


@pytest.mark.parametrize("poses", [30, 60])
def test_rows_bounded_still_samples_exact_extremes_per_bucket(results, tmp_path, monkeypatch,
                                                              poses):
    r = results[poses]
    s = r.session
    path = tmp_path / "rec.rrd"
    rows = _save(r, path, monkeypatch, still_rows=10**9)
    assert len(s.t_acc) > 4 * SCREEN  # long enough for the rule to bite

    # Per-axis plots and the detector: at most a screen's rows, whatever the length.
    for p in (P.ACC_RAW, P.ACC_CALIBRATED, P.GYRO_RAW, P.GYRO_CALIBRATED, P.DETECTOR_STATISTIC):
        t, v = rb.scalars(path, p)
        assert rows[p] == len(t) <= SCREEN, p
    _, ax = rb.scalars(path, P.ACC_RAW)
    np.testing.assert_array_equal(ax.max(axis=0), s.acc.max(axis=0))
    np.testing.assert_array_equal(ax.min(axis=0), s.acc.min(axis=0))

    # Accelerometer magnitude: every still sample exact, the motion bounded, per bucket.
    acc = np.column_stack([r.raw_acc_norm, r.calibrated.acc_norm])
    still, moving = runs_of_true(r.acc_still), runs_of_true(~r.acc_still)
    info = rb.values(path, P.ACC_MAGNITUDE)
    assert (info["samples"], info["still_bucket"]) == (len(s.t_acc), 1)
    t, v = rb.scalars(path, P.ACC_MAGNITUDE)
    k_still = _check_runs(t, v, s.t_acc, acc, still, 1)
    assert np.count_nonzero(k_still >= 0) == r.acc_still.sum()
    k_moving = _check_runs(t, v, s.t_acc, acc, moving, info["moving_bucket"])
    assert np.all((k_still >= 0) != (k_moving >= 0))  # every row in one run: none straddles
    assert np.count_nonzero(k_moving >= 0) <= SCREEN < (~r.acc_still).sum()
    assert info["rows"] == rows[P.ACC_MAGNITUDE] == len(t)

    # Gyroscope magnitude: envelopes in and between the blocks, each inside one run.
    gyro = np.column_stack([r.raw_gyro_norm, r.calibrated.gyro_norm])
    info = rb.values(path, P.GYRO_MAGNITUDE)
    assert info["still_bucket"] > 1 and info["moving_bucket"] > 1
    t, v = rb.scalars(path, P.GYRO_MAGNITUDE)
    assert len(t) <= 2 * SCREEN
    _check_runs(t, v, s.t_gyro, gyro, runs_of_true(r.gyro_still), info["still_bucket"])
    _check_runs(t, v, s.t_gyro, gyro, runs_of_true(~r.gyro_still), info["moving_bucket"])
    assert v[:, 1].max() == r.calibrated.gyro_norm.max()


def test_row_counts_do_not_grow_with_the_session(results, tmp_path, monkeypatch):
    """Twice the session: the same rows outside the still blocks; the still blocks' own
    rows grow with them only while under STILL_ROWS."""
    out = {}
    for poses, r in results.items():
        path = tmp_path / f"{poses}.rrd"
        _save(r, path, monkeypatch, still_rows=10**9)
        t, _ = rb.scalars(path, P.ACC_MAGNITUDE)
        k = _in_runs(t, r.session.t_acc, runs_of_true(r.acc_still))
        out[poses] = {p: n for p, n in rb.entities(path).items()
                      if p.startswith(("imu/", "detector/statistic"))}
        out[poses]["moving"] = int(np.count_nonzero(k < 0))
        out[poses]["still"] = int(np.count_nonzero(k >= 0))
    short, long = out[30], out[60]
    assert long["still"] > 1.8 * short["still"]
    for p in short:
        if p not in ("still", P.ACC_MAGNITUDE):
            # within one partial bucket per run of the budget, for both lengths
            assert abs(long[p] - short[p]) <= 0.1 * SCREEN, (p, short[p], long[p])
            assert long[p] <= 2 * SCREEN


def test_still_samples_past_the_budget_become_an_envelope_inside_each_block(results, tmp_path,
                                                                            monkeypatch):
    r = results[60]
    s = r.session
    path = tmp_path / "budget.rrd"
    n_still = int(r.acc_still.sum())
    _save(r, path, monkeypatch, still_rows=n_still // 3)
    info = rb.values(path, P.ACC_MAGNITUDE)
    assert info["still_bucket"] >= 3
    acc = np.column_stack([r.raw_acc_norm, r.calibrated.acc_norm])
    t, v = rb.scalars(path, P.ACC_MAGNITUDE)
    still = runs_of_true(r.acc_still)
    k = _check_runs(t, v, s.t_acc, acc, still, info["still_bucket"])
    assert np.count_nonzero(k >= 0) <= n_still // 3
    # each block's extremes kept exactly
    for j, (a, b) in enumerate(still):
        np.testing.assert_array_equal(v[k == j].max(axis=0), acc[a:b].max(axis=0))
        np.testing.assert_array_equal(v[k == j].min(axis=0), acc[a:b].min(axis=0))


def test_bucket_size_is_the_smallest_that_fits():
    rng = np.random.default_rng(4)
    for _ in range(50):
        lengths = rng.integers(1, 400, rng.integers(1, 30))
        ends = np.cumsum(lengths + rng.integers(0, 5, len(lengths)))
        runs = np.column_stack([ends - lengths, ends])
        max_rows = int(rng.integers(2, 3000))
        size = D.bucket_size(runs, max_rows)
        count = int((-(-lengths // size)).sum())
        if max_rows // 2 <= len(lengths):  # too small a budget: one bucket per run
            assert size == lengths.max()
            continue
        assert count <= max_rows // 2
        assert size == 1 or int((-(-lengths // (size - 1))).sum()) > max_rows // 2


def test_envelope_of_nothing_to_cut_is_the_signal_itself():
    t = np.arange(10.0)
    x = np.arange(30.0).reshape(10, 3)
    still = np.zeros(10, bool)
    still[3:6] = True
    tt, vv, d = magnitudes_for_display(t, x, still, keep_still=True)
    assert tt is t and vv is x and (d.rows, d.still_bucket, d.moving_bucket) == (10, 1, 1)
