"""The signals' rows and the layout's ranges made a chunk of rows at a time (viewer/signal_rows.py,
issue 12) are those of the whole arrays, to the bit, however the chunks fall.

The reference is the whole-array code the recording used before: the calibrated signals and
magnitudes made whole, the still samples as a mask, one envelope over everything, np.quantile
of the concatenated magnitudes. Limits and chunks are lowered so that small sessions cross every
edge: buckets across chunks, chunks across the calibration's pieces, still blocks in between.
"""

from __future__ import annotations

import numpy as np
import pytest

import imucal
import viewer.decimate as D
import viewer.ranges as R
import viewer.signal_rows as S
from imucal.numerics.windows import mask_of_runs, runs_of_true
from imucal.synth import make_session
from viewer.columns import log10_axis
from viewer.stream import EnvelopeStream


@pytest.fixture(scope="module")
def two_segments():
    """Two segments (a gap between them takes the neighbours' mean model), the gyroscope on a
    clock of its own."""
    s, _ = make_session(poses=40, seed=5, acc_rate=200.0, gyro_rate=130.0, change_at=0.5)
    r = imucal.calibrate(s)
    assert len(r.segments) == 2
    return r


def _whole_magnitudes(t, v, still, keep_still):
    """The former viewer.decimate.magnitudes_for_display: both kinds of runs from the mask,
    one envelope each over the whole signal, merged by time."""
    still_rows = D.STILL_ROWS if keep_still else D.SCREEN_ROWS
    n_still = int(still.sum())
    runs_still, runs_moving = runs_of_true(still), runs_of_true(~still)
    s_size = 1 if n_still <= still_rows else D.bucket_size(runs_still, still_rows)
    m_size = 1 if len(t) - n_still <= D.SCREEN_ROWS else D.bucket_size(runs_moving,
                                                                         D.SCREEN_ROWS)
    if s_size == 1 and m_size == 1:
        return t, v, (s_size, m_size)
    parts = [D.run_envelope(t, v, runs, size)
             for runs, size in ((runs_still, s_size), (runs_moving, m_size))]
    tt = np.concatenate([p[0] for p in parts])
    order = np.argsort(tt, kind="stable")
    return tt[order], np.concatenate([p[1] for p in parts])[order], (s_size, m_size)


def _same(series, t, v, buckets=None):
    np.testing.assert_array_equal(series.t, t)
    np.testing.assert_array_equal(series.v, v)
    assert series.decimation.rows == len(t)
    if buckets is not None:
        assert (series.decimation.still_bucket, series.decimation.moving_bucket) == buckets


@pytest.mark.parametrize("chunk", [997, 4096, 1 << 16])
def test_rows_and_ranges_are_the_whole_arrays(two_segments, monkeypatch, chunk):
    r = two_segments
    monkeypatch.setattr(D, "SCREEN_ROWS", 500)
    monkeypatch.setattr(D, "STILL_ROWS", 3000)
    monkeypatch.setattr(S, "CHUNK", chunk)
    monkeypatch.setattr(R, "SAMPLE", 2000)  # brackets narrower than the values: two passes
    got = S.signal_rows(r)
    s, cal = r.session, r.calibrated

    acc = np.column_stack([r.raw_acc_norm, cal.acc_norm])
    t, v, buckets = _whole_magnitudes(s.t_acc, acc, r.acc_still, keep_still=True)
    assert buckets[0] > 1 and buckets[1] > 1  # both envelopes, in and between the blocks
    _same(got.acc.magnitude, t, v, buckets)
    _same(got.acc.raw, *D.envelope(s.t_acc, s.acc, D.SCREEN_ROWS))
    _same(got.acc.calibrated, *D.envelope(s.t_acc, cal.acc, D.SCREEN_ROWS))
    assert got.acc.y_range == R.robust_range(np.concatenate([acc[:, 0], acc[:, 1]]))

    gyro = np.column_stack([r.raw_gyro_norm, cal.gyro_norm])
    t, v, buckets = _whole_magnitudes(s.t_gyro, gyro, r.gyro_still, keep_still=False)
    _same(got.gyro.magnitude, t, v, buckets)
    _same(got.gyro.raw, *D.envelope(s.t_gyro, s.gyro, D.SCREEN_ROWS))
    _same(got.gyro.calibrated, *D.envelope(s.t_gyro, cal.gyro, D.SCREEN_ROWS))
    assert got.gyro.y_range == R.robust_range(np.concatenate([gyro[:, 0], gyro[:, 1]]),
                                              q=0.0005)

    stat = r.detection.statistic(s.acc)
    _same(got.detector, *D.envelope(s.t_acc, log10_axis(stat), D.SCREEN_ROWS))
    assert got.detector_range == R.robust_range(np.append(
        np.log10(stat[stat > 0]), np.log10(r.detection.threshold)), q=0.0)


def test_row_edges_fall_on_the_calibration_pieces(two_segments):
    r = two_segments
    for which, t in (("acc", r.session.t_acc), ("gyro", r.session.t_gyro)):
        edges = r.row_edges(which, 1000)
        assert edges[0] == 0 and edges[-1] == len(t) and np.all(np.diff(edges) <= 1000)
        seg = r.calibration.segments
        # each segment's first sample and the first after it start a chunk (its grid's)
        for s0, s1 in zip(seg[:-1], seg[1:]):
            for time, side in ((s0.t_end, "right"), (s1.t_start, "left")):
                assert int(np.searchsorted(t, time, side=side)) in edges
        rows = r.calibrated_rows.acc if which == "acc" else r.calibrated_rows.gyro
        whole = r.calibrated.acc if which == "acc" else r.calibrated.gyro
        np.testing.assert_array_equal(
            np.concatenate([rows(a, b) for a, b in zip(edges[:-1], edges[1:])]), whole)
        raw = r.raw_acc_norm_rows if which == "acc" else r.raw_gyro_norm_rows
        np.testing.assert_array_equal(
            np.concatenate([raw(a, b) for a, b in zip(edges[:-1], edges[1:])]),
            r.raw_acc_norm if which == "acc" else r.raw_gyro_norm)


def test_union_runs_and_gaps_are_the_masks_runs():
    rng = np.random.default_rng(5)
    for _ in range(200):
        n = int(rng.integers(1, 300))
        starts = rng.integers(-5, n + 5, int(rng.integers(0, 12)))
        runs = np.column_stack([starts, starts + rng.integers(0, 40, len(starts))])
        mask = mask_of_runs(runs, n)
        merged = D.union_runs(runs, n)
        np.testing.assert_array_equal(merged, runs_of_true(mask).reshape(-1, 2))
        np.testing.assert_array_equal(D.gaps(merged, n), runs_of_true(~mask).reshape(-1, 2))


def test_stream_fed_in_any_pieces_is_the_whole_envelope():
    rng = np.random.default_rng(8)
    for _ in range(40):
        n = int(rng.integers(50, 3000))
        t = np.cumsum(rng.uniform(0.5, 1.5, n))
        x = rng.normal(size=(n, 2))
        blocks = np.sort(rng.integers(0, n, 2 * int(rng.integers(0, 8)))).reshape(-1, 2)
        cut = D.magnitude_cut(blocks, n, keep_still=bool(rng.integers(2)))
        whole = EnvelopeStream(t, cut)
        whole.feed(x)
        pieces = EnvelopeStream(t, cut)
        edges = np.unique(np.concatenate([[0, n], rng.integers(0, n, 20)]))
        for a, b in zip(edges[:-1], edges[1:]):  # pieces shorter and longer than a bucket
            pieces.feed(x[a:b])
        for u, v in zip(whole.rows(), pieces.rows()):
            np.testing.assert_array_equal(np.asarray(u), np.asarray(v))


def test_ranges_are_numpys_to_the_bit(monkeypatch):
    monkeypatch.setattr(R, "SAMPLE", 300)  # the fallback's brackets narrower than the values
    rng = np.random.default_rng(2)
    for i in range(120):
        n = int(rng.integers(2, 20_000))
        v = [rng.standard_normal(n), np.round(rng.standard_normal(n), 1),
             rng.integers(0, 4, n).astype(float)][i % 3]
        v[rng.integers(0, n, 3)] = 50.0  # spikes
        q = float(rng.choice([0.0, 0.0005, 0.005, 0.25, 0.5]))
        step = int(rng.integers(1, 3000))

        def chunks(v=v, step=step):
            return (v[a:a + step] for a in range(0, len(v), step))

        assert R.quantiles(chunks, n, [q, 1 - q]) == list(np.quantile(v, [q, 1 - q]))
        # one pass, the tails kept; and with a bound too small, the fallback's two passes
        for n_max in (n, n // 3):
            one = R.RobustRange(n_max, q)
            for c in chunks():
                one.add(c)
            assert one.result(chunks) == R.robust_range(v, q), (n, q, n_max)


def test_nan_and_inf_are_left_out_of_a_range_as_before():
    v = np.array([np.nan, 1.0, np.inf, 2.0, 3.0, -np.inf, 2.5])
    one = R.RobustRange(len(v), 0.1)
    for c in (v[:3], v[3:]):
        one.add(c)
    assert one.count == 4
    assert one.result(lambda: iter(())) == R.robust_range(v, 0.1)
    assert R.RobustRange(5, 0.1).result(lambda: iter(())) is None  # nothing: the viewer's own
