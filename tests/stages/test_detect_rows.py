"""The static detector and its checks read the session a block of rows at a time (issue 12): the
same detection from an array that offers only slices and gathers (tests/row_only.py) as from
the whole array, and the streamed statistic's runs are the array formula's to the bit."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from row_only import RowOnly

import imucal.numerics.rows as rows_module
import imucal.stages.detect as detect
import imucal.stages.detect_runs as detect_runs
import imucal.stages.detect_stat as detect_stat
from imucal.numerics.windows import rolling_variance
from imucal.settings import Settings
from imucal.stages.detect import detect_static, isolated_outliers, wander_ratio
from imucal.stages.detect_runs import still_runs, streamed_still_runs
from imucal.stages.detect_stat import CleanRows, Statistic, combine_variances, rolling_statistic
from imucal.stages.detect_tuning import local_factor, tune_detector
from imucal.stages.sanity import coverage_warning, split_at_gaps, time_gaps, turns_without_gyro
from imucal.stages.saturation import saturated_runs
from imucal.synth import make_session


@pytest.fixture
def small_spans(monkeypatch):
    """Spans of 3000 samples and open runs of 7000: a short session crosses many of each."""
    monkeypatch.setattr(detect_stat, "SPAN", 3000)
    monkeypatch.setattr(detect_runs, "OPEN_LIMIT", 7000)
    monkeypatch.setattr(detect, "ROWS", 5000)
    monkeypatch.setattr(rows_module, "ROWS", 1000)


def _glitched(seed: int = 5, **kw):
    session, _ = make_session(poses=16, seed=seed, acc_rate=200.0, **kw)
    acc = session.acc.copy()
    acc[[0, 2000, 4321, len(acc) - 1], [1, 0, 2, 2]] += [3.0, 1e9, -2.0, 4.0]
    return dataclasses.replace(session, acc=acc)


def _same_detection(a, b) -> None:
    for name in ("threshold", "s2_init", "window", "min_len", "k", "init", "note",
                 "outlier_note", "orientations", "tuning"):
        assert getattr(a, name) == getattr(b, name), name
    np.testing.assert_array_equal(a.blocks, b.blocks)
    np.testing.assert_array_equal(a.means, b.means)
    np.testing.assert_array_equal(a.outliers, b.outliers)


@pytest.mark.parametrize("overrides", [{}, {"k": 3.0}, {"init": (40.0, 43.0)},
                                       {"statistic": "imu_tk"}])
def test_tuned_detection_from_slices_is_the_arrays(small_spans, overrides) -> None:
    """Spans, open runs and outlier reads much shorter than the session; the initial interval
    moved to where the device turns (40-43 s): the quiet level is the reference."""
    session = _glitched()
    settings = dataclasses.replace(Settings().detect, **overrides)
    whole = tune_detector(session.acc, session.t_acc, settings)
    acc, t = RowOnly(session.acc), RowOnly(session.t_acc)
    rows = tune_detector(acc, t, settings)
    _same_detection(whole, rows)
    assert len(whole.outliers) == 4 and len(whole.blocks) >= 12
    assert acc.rows_read < 15 * len(session.acc)  # a few passes, however it is cut
    np.testing.assert_array_equal(whole.statistic(acc), whole.statistic(session.acc))


@pytest.mark.parametrize("init", [None, (40.0, 43.0)])
def test_plain_detection_from_slices_is_the_arrays(small_spans, init) -> None:
    """The thesis's detector; an initial interval where the device turns slides to the first
    still stretch after it (the clock searched through slices)."""
    session = _glitched(seed=3)
    settings = Settings(init=init).detect
    whole = detect_static(session.acc, session.t_acc, settings)
    rows = detect_static(RowOnly(session.acc), RowOnly(session.t_acc), settings)
    _same_detection(whole, rows)
    assert "sample 2000 " in whole.outlier_note  # the absurd one is named
    assert (whole.note is None) == (init is None)


@pytest.mark.parametrize("statistic", ["thesis", "imu_tk"])
def test_spans_of_m1_are_the_whole_signals(small_spans, statistic) -> None:
    """Span by span, M1 agrees with the rolling variance of the whole signal (to rounding:
    each span is centred on its own mean), and a short signal is that computation itself."""
    session = _glitched()
    clean = CleanRows(session.acc, isolated_outliers(session.acc))
    whole = combine_variances(rolling_variance(clean[0:len(clean)], 101), statistic)
    spans = rolling_statistic(clean, 101, statistic, span=3000)
    np.testing.assert_allclose(spans, whole, rtol=1e-6, atol=1e-30)
    short = rolling_statistic(clean, 101, statistic, span=1 << 17)
    np.testing.assert_array_equal(short, whole)


def _whole_signal_statistic(x: np.ndarray, w: int, statistic: str) -> np.ndarray:
    """rolling_statistic as it was (the reference): spans of 2^17 of the whole array, each
    centred on its mean, running sums restarted every max(16384, 2w) samples."""
    n, k = x.shape
    left, span = w // 2, 1 << 17
    b = max(16384, 2 * w)
    stat = np.empty(n)
    for o0 in range(0, n, span):
        o1 = min(n, o0 + span)
        idx = np.arange(o0 - left, o1 - left + w - 1)
        idx = np.where(idx < 0, -idx, np.where(idx > n - 1, 2 * (n - 1) - idx, idx))
        z = x[idx]
        length = len(z)
        y = np.empty((2 * k, length))
        y[:k] = z.T
        y[:k] -= y[:k].mean(axis=1, keepdims=True)
        np.multiply(y[:k], y[:k], out=y[k:])
        nch = -(-(length + 1) // b)
        Y = np.zeros((2 * k, nch * b))
        Y[:, :length] = y
        Y = Y.reshape(2 * k, nch, b)
        E = np.cumsum(Y, axis=2)
        T = E[:, :, -1].copy()
        E -= Y
        S = Y
        np.subtract(E[:, :, w:], E[:, :, :b - w], out=S[:, :, :b - w])
        np.subtract(E[:, 1:, :w], E[:, :-1, b - w:], out=S[:, :-1, b - w:])
        S[:, :-1, b - w:] += T[:, :-1, None]
        m = S.reshape(2 * k, -1)[:, :o1 - o0] / 1.0
        m *= 1.0 / w
        v = np.maximum(m[k:] - m[:k] * m[:k], 0.0) * (w / (w - 1))
        out = stat[o0:o1]
        np.multiply(v[0], v[0], out=out)
        for j in range(1, k):
            out += v[j] * v[j]
    return stat if statistic == "thesis" else np.sqrt(stat)


@pytest.mark.parametrize("w, statistic", [(1011, "thesis"), (253, "imu_tk"), (101, "thesis")])
def test_m1_over_long_signals_is_the_whole_signal_computation(w, statistic) -> None:
    """More than two spans (the ends mirrored, a last span cut short): M1 to the bit."""
    rng = np.random.default_rng(w)
    x = rng.normal(0.0, 0.003, (300_007, 3)) + np.repeat(rng.normal(size=(61, 3)), 4919,
                                                         axis=0)[:300_007]
    expected = _whole_signal_statistic(x, w, statistic)
    np.testing.assert_array_equal(rolling_statistic(RowOnly(x), w, statistic), expected)
    det_like = CleanRows(RowOnly(x), np.zeros(0, np.int64))
    np.testing.assert_array_equal(rolling_statistic(det_like, w, statistic), expected)


@pytest.mark.parametrize("k, local", [(4.0, None), (8.0, "thesis"), (64.0, "thesis")])
def test_streamed_runs_are_the_array_formulas(small_spans, k, local) -> None:
    """Local ends from run medians: runs longer than OPEN_LIMIT are let go and redone; the
    runs agree with still_runs on M1 made whole, to the sample."""
    session = _glitched(init_still=60.0)
    outliers = isolated_outliers(session.acc)
    clean = CleanRows(RowOnly(session.acc), outliers)
    stat = Statistic(clean, 101)
    values = rolling_statistic(clean, 101, span=3000)
    ref = float(np.quantile(values, 0.05))
    q = local_factor(101, local) if local else None
    expected = still_runs(values.copy(), k * ref, q, outliers)
    mask = values < k * ref
    mask[outliers] = False
    total = int(mask.sum())
    assert np.max(expected[:, 1] - expected[:, 0]) > 7000  # some are redone
    for count in (total, None):
        got = streamed_still_runs(stat, k * ref, q, outliers, count)
        np.testing.assert_array_equal(got, expected)


def _whole_signal_outliers(x: np.ndarray) -> np.ndarray:
    """isolated_outliers as it was, on the whole signal at once (the reference)."""
    x = np.asarray(x, dtype=np.float64)
    n = len(x)
    stride = max(1, n // 200_000)
    found = []
    for j in range(x.shape[1]):
        c = x[:, j]
        e = np.empty(n)
        np.add(c[:-2], c[2:], out=e[1:-1])
        e[0], e[-1] = c[1] + c[1], c[-2] + c[-2]
        e *= -0.5
        e += c
        np.abs(e, out=e)
        scale = 1.4826 * float(np.median(e[::stride]))
        if scale == 0.0:
            scale = float(np.mean(e))
        if scale == 0.0 or not np.isfinite(scale):
            continue
        i = np.flatnonzero(e > 50.0 * scale)
        m = lambda k: np.where(k < 0, -k, np.where(k > n - 1, 2 * (n - 1) - k, k))  # noqa: E731
        prev2, prev, nxt, nxt2 = (c[m(i + d)] for d in (-2, -1, 1, 2))
        steps = np.maximum.reduce([np.abs(nxt - prev), np.abs(nxt2 - nxt),
                                   np.abs(prev - prev2)])
        found.append(i[e[i] > 5.0 * steps])
    return np.unique(np.concatenate(found)) if found else np.zeros(0, np.int64)


def test_isolated_outliers_a_block_at_a_time(small_spans) -> None:
    """Read 5000 rows at a time (and the scale from a gather): the spikes of the whole-signal
    rule, among them the first and last samples; a quantised signal takes the mean of |e|,
    numpy's pairwise sum put together from parts of 1000."""
    session = _glitched()
    found = isolated_outliers(RowOnly(session.acc))
    assert found.tolist() == [0, 2000, 4321, len(session.acc) - 1]
    np.testing.assert_array_equal(found, _whole_signal_outliers(session.acc))
    q = np.round(session.acc * 40.0)  # steps of 25 mg: most samples equal their neighbours
    q[[100, 7000], [0, 1]] += 30.0
    assert np.median(np.abs(q[1:-1] - 0.5 * (q[:-2] + q[2:]))) == 0.0
    quantised = isolated_outliers(RowOnly(q))
    np.testing.assert_array_equal(quantised, _whole_signal_outliers(q))
    assert 7000 in quantised


def test_wander_ratio_of_a_long_stretch_read_in_blocks(monkeypatch) -> None:
    """Longer than a read: the parts' means and variances summed in order across reads, the
    same to the bit as the reshaped whole."""
    rng = np.random.default_rng(2)
    x = rng.normal(0.0, 0.01, (50_003, 3)) + [0.2, -0.1, 1000.0]
    expected = wander_ratio(x)
    monkeypatch.setattr(detect, "ROWS", 4096)
    assert wander_ratio(RowOnly(x)) == expected
    x[30_000:] += 0.05  # a pose change in part four: the means wander
    assert wander_ratio(RowOnly(x)) > 100 * expected


def test_saturation_and_gaps_from_slices() -> None:
    rng = np.random.default_rng(7)
    n = 1_200_000  # more steps than a median of steps keeps whole
    x = rng.normal(0.0, 0.01, (n, 3))
    x[5000:5100, 1] = x[:, 1].max() + 1.0  # clipped
    t = np.cumsum(rng.uniform(0.0009, 0.0011, n))
    t[700_000:] += 0.5  # a gap
    rows = saturated_runs(RowOnly(x), chunk=1 << 15)
    assert rows.tolist() == [[5000, 5100]]
    np.testing.assert_array_equal(rows, saturated_runs(x))
    step = np.diff(t)
    expected = np.flatnonzero(step > 10.0 * np.quantile(step, 0.99))
    assert expected.tolist() == [699_999]
    np.testing.assert_array_equal(time_gaps(RowOnly(t)), expected)
    steady = np.arange(n) / 1000.0
    assert len(time_gaps(RowOnly(steady))) == 0


def test_blocks_are_cut_at_gaps_from_slices() -> None:
    session, _ = make_session(poses=12, seed=3)
    t = session.t_acc.copy()
    det = detect_static(session.acc, t)
    a, b = det.blocks[4]
    t[(a + b) // 2:] += 30.0  # nothing recorded for 30 s in the middle of block 4
    whole = split_at_gaps(det, session.acc, t)
    rows = split_at_gaps(det, RowOnly(session.acc), RowOnly(t))
    assert len(whole.blocks) == len(det.blocks) + 1
    np.testing.assert_array_equal(rows.blocks, whole.blocks)
    np.testing.assert_array_equal(rows.means, whole.means)


def test_gyroscope_coverage_from_slices() -> None:
    """A gyroscope that stops early and has a gap: the same turns and blocks without it, and
    the same warning, with the clocks read through slices."""
    session, _ = make_session(poses=12, seed=3)
    det = detect_static(session.acc, session.t_acc)
    times = np.column_stack([session.t_acc[det.blocks[:, 0]], session.t_acc[det.blocks[:, 1] - 1]])
    keep = np.r_[0:2000, 2400:int(0.7 * len(session.t_gyro))]
    cut = dataclasses.replace(session, gyro=session.gyro[keep], t_gyro=session.t_gyro[keep])
    rows = dataclasses.replace(cut, t_acc=RowOnly(cut.t_acc), t_gyro=RowOnly(cut.t_gyro),
                               gyro=RowOnly(cut.gyro))
    warning = coverage_warning(cut, times)
    assert warning is not None and "turn" in warning.text
    assert coverage_warning(rows, times) == warning
    np.testing.assert_array_equal(turns_without_gyro(rows.t_gyro, times),
                                  turns_without_gyro(cut.t_gyro, times))
