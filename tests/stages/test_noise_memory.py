"""The noise figures and the sample rates without signal-sized arrays (issue 12: +743 MB and
+346 MB at 6 hours of 1 kHz): the pooled Allan variance reads its blocks through a row getter and
streams the running sum, the rates are an exact median found a chunk at a time. The numbers are
the whole-array formulas' to the bit (written out here as they were), the allocations a small
part of what those made. Allocations are measured with tracemalloc, not timed."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest
from row_only import RowOnly

import imucal
from imucal.numerics.allan import pooled_allan_variance
from imucal.session import Session, chunked_median, median_step
from imucal.stages.noise import still_noise
from imucal.synth import make_session


def _peak(f, *args, **kwargs):
    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        before, _ = tracemalloc.get_traced_memory()
        out = f(*args, **kwargs)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return out, peak - before


def _packed_reference(x, starts, ends, min_clusters=3.0, chunk=1 << 16):
    """The pooled estimator as it was: the runs packed into one running sum of every still
    sample, and an int64 of the samples left in each run."""
    x = np.asarray(x, dtype=np.float64).reshape(len(x), -1)
    lengths = ends - starts
    n, k = int(lengths.sum()), x.shape[1]
    run_start = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    S = np.zeros((n + 1, k))
    for a, b, p in zip(starts, ends, run_start):
        np.subtract(x[a:b], x[a:b].mean(axis=0), out=S[p + 1:p + 1 + b - a])
    np.cumsum(S[1:], axis=0, out=S[1:])
    remaining = np.repeat(run_start + lengths, lengths) - np.arange(n)
    lags, avar, terms = [], [], []
    m = 1
    while m * min_clusters <= int(lengths.max()):
        total, count = np.zeros(k), 0
        for lo in range(0, n - 2 * m + 1, chunk):
            hi = min(lo + chunk, n - 2 * m + 1)
            valid = remaining[lo:hi] >= 2 * m
            d = S[lo + 2 * m:hi + 2 * m] - 2.0 * S[lo + m:hi + m]
            d += S[lo:hi]
            total += np.einsum("ij,ij,i->j", d, d, valid.astype(np.float64))
            count += int(np.count_nonzero(valid))
        if count:
            lags.append(m)
            avar.append(total / (2.0 * m * m * count))
            terms.append(count)
        m *= 2
    return np.asarray(lags), np.asarray(avar).reshape(-1, k), np.asarray(terms)


def _blocks(rng, n, count, longest):
    lengths = rng.integers(2, longest, count)
    gaps = rng.integers(1, max(2, (n - lengths.sum()) // count), count)
    starts = np.cumsum(gaps + np.concatenate([[0], lengths[:-1]]))
    keep = starts + lengths <= n
    return starts[keep], (starts + lengths)[keep]


@pytest.mark.parametrize("seed, chunk", [(0, 1 << 16), (1, 1000), (2, 7)])
def test_pooled_allan_variance_from_a_row_getter_is_the_packed_formula(seed, chunk) -> None:
    rng = np.random.default_rng(seed)
    n = 60_000
    x = rng.normal(0.0, 1e-3, (n, 3)) + np.cumsum(rng.normal(0.0, 1e-6, (n, 3)), axis=0) + 0.5
    starts, ends = _blocks(rng, n, 25, 4000)
    lags, avar, terms = _packed_reference(x, starts, ends, chunk=chunk)
    calls = []

    def rows(a, b):
        calls.append((a, b))
        return x[a:b] * 1.0  # a fresh array, as Calibration.rows gives

    for source in (x, np.asfortranarray(x), rows):
        curve = pooled_allan_variance(source, starts, ends, chunk=chunk)
        ref = (lags, avar, terms) if source is not rows else _packed_reference(
            np.ascontiguousarray(x), starts, ends, chunk=chunk)
        if source is not x and source is not rows:  # a Fortran-ordered array, as given
            ref = _packed_reference(source, starts, ends, chunk=chunk)
        assert np.array_equal(curve.lags, ref[0])
        assert np.array_equal(curve.avar, ref[1])  # to the bit
        assert np.array_equal(curve.terms, ref[2])
        assert curve.n == int(np.sum(ends - starts))
    assert all(a >= starts[0] and b <= ends[-1] for a, b in calls)


def test_pooled_allan_variance_holds_a_window_not_the_still_samples() -> None:
    rng = np.random.default_rng(5)
    n = 2_000_000
    x = rng.normal(0.0, 1e-3, (n, 3))
    starts, ends = _blocks(rng, n, 300, 10_000)
    still = int(np.sum(ends - starts))
    curve, peak = _peak(pooled_allan_variance, lambda a, b: x[a:b] * 1.0, starts, ends)
    ref = _packed_reference(x, starts, ends)
    assert np.array_equal(curve.avar, ref[1])
    # The packed formula held 32 bytes per still sample (S and `remaining`) on top of the
    # 24 of the packed samples; this holds a read (2^18 rows) and a window of S.
    assert still > 1_000_000
    assert peak < 0.4 * 24 * still


@pytest.mark.parametrize("t", [
    np.arange(1_500_001) / 1000.0,  # a clock whose steps differ in their last bits (odd count)
    np.arange(1_400_000, dtype=float),  # every step equal: all ties
    np.cumsum(np.random.default_rng(4).uniform(0.0009, 0.0011, 1_300_000)),  # jitter, even
    np.concatenate([np.arange(700_000) * 0.01, 7_100 + np.arange(700_000) * 0.0025]),  # two
])
def test_session_rate_is_numpy_median_without_the_steps(t) -> None:
    s = Session(acc=np.zeros((len(t), 3)), t_acc=t, gyro=np.zeros((len(t), 3)), t_gyro=t)
    rate, peak = _peak(lambda: s.acc_rate)
    assert rate == float(1.0 / np.median(np.diff(t)))
    assert s.gyro_rate == rate
    assert peak < 0.35 * t.nbytes  # a sample of 2^17 steps and a chunk; np.diff + copy: 2.0


@pytest.mark.parametrize("n", [2, 3, 1000, 1001])
def test_chunked_median_small_brackets_and_block_steps(n) -> None:
    rng = np.random.default_rng(n)
    v = np.round(rng.normal(1.0, 0.01, n), 3)  # ties at the bracket's ends
    chunks = lambda: (v[i:i + 97] for i in range(0, n, 97))  # noqa: E731
    assert chunked_median(chunks, n, small=1) == float(np.median(v))
    t = np.cumsum(rng.uniform(0.5, 1.5, 5 * n))
    ranges = [(a, a + n // 2 + 1) for a in range(0, 4 * n, n)]
    steps = np.concatenate([np.diff(t[a:b]) for a, b in ranges])
    assert median_step(t, ranges) == float(np.median(steps))


def test_result_noise_from_rows_is_the_whole_signals_noise() -> None:
    session, _ = make_session(poses=14, seed=8, acc_noise=0.004, gyro_noise=0.002,
                              acc_rate=200.0, gyro_rate=100.0)
    result = imucal.calibrate(session)
    from_rows = result.noise  # before the calibrated signals exist: rows through a getter
    whole = still_noise(result.calibrated, result.block_times)
    assert "calibrated" in result.__dict__
    for a, b in ((from_rows.accelerometer, whole.accelerometer),
                 (from_rows.gyroscope, whole.gyroscope)):
        assert np.array_equal(a.curve.avar, b.curve.avar)
        assert np.array_equal(a.curve.lags, b.curve.lags)
        assert a.rate_hz == b.rate_hz
        assert a.per_axis("white") == b.per_axis("white")


def test_pooled_allan_variance_of_runs_across_many_reads() -> None:
    """Runs longer than a read (2^16 rows) and runs meeting at a read's edge: put together
    from their reads (a getter), or sliced whole (an array, in its own layout)."""
    rng = np.random.default_rng(9)
    n = 600_000
    x = rng.normal(0.0, 1e-3, (n, 3)) + np.cumsum(rng.normal(0.0, 1e-6, (n, 3)), axis=0)
    starts = np.array([10, 65_530, 65_536, 131_072, 200_001, 330_000, 599_000])
    ends = np.array([65_530, 65_536, 131_071, 199_000, 329_999, 598_000, n])
    lags, avar, terms = _packed_reference(x, starts, ends)
    for source in (x, lambda a, b: x[a:b] * 1.0):
        curve = pooled_allan_variance(source, starts, ends)
        assert np.array_equal(curve.avar, avar) and np.array_equal(curve.terms, terms)
    fortran = np.asfortranarray(x)
    curve = pooled_allan_variance(fortran, starts, ends)
    assert np.array_equal(curve.avar, _packed_reference(fortran, starts, ends)[1])


@pytest.mark.parametrize("shared", [False, True])
def test_still_noise_reads_the_clocks_through_slices(shared) -> None:
    """The blocks' edges searched and the rates found through slices of the time arrays
    (tests/row_only.py); a gyroscope on the accelerometer's own clock shares them."""
    session, _ = make_session(poses=14, seed=8, acc_rate=200.0, gyro_rate=200.0 if shared
                              else 100.0)
    result = imucal.calibrate(session)
    cal = result.calibrated
    whole = still_noise(cal, result.block_times)
    t_acc = RowOnly(cal.t_acc)

    class Source:
        acc_unit = cal.acc_unit

        def __init__(self):
            self.t_acc = t_acc
            self.t_gyro = t_acc if shared else RowOnly(cal.t_gyro)

        def acc(self, a, b):
            return cal.acc[a:b] * 1.0

        def gyro(self, a, b):
            return cal.gyro[a:b] * 1.0

    rows = still_noise(Source(), result.block_times)
    for a, b in ((rows.accelerometer, whole.accelerometer), (rows.gyroscope, whole.gyroscope)):
        assert np.array_equal(a.curve.avar, b.curve.avar) and a.rate_hz == b.rate_hz


@pytest.mark.parametrize("seed", [0, 1])
def test_six_columns_are_each_sensors_own_curve(seed) -> None:
    """One clock's two sensors pooled side by side (still_noise's shared pass) give each
    sensor's three-column curve to the bit; the runs vary in length, so the long lags take
    the slices computed point by point (most points past their run's end) and the short ones
    the slices computed whole."""
    rng = np.random.default_rng(seed)
    n = 300_000
    x = rng.normal(0.0, 1e-3, (n, 6)) * [1, 2, 3, 50, 60, 70] + np.cumsum(
        rng.normal(0.0, 1e-6, (n, 6)), axis=0) + [0.1, -0.2, 0.98, 1e-3, -2e-3, 5e-4]
    starts, ends = _blocks(rng, n, 60, 12_000)
    six = pooled_allan_variance(lambda a, b: x[a:b] * 1.0, starts, ends, width=6)
    for cols in (slice(0, 3), slice(3, 6)):
        part = np.ascontiguousarray(x[:, cols])
        three = pooled_allan_variance(lambda a, b, p=part: p[a:b] * 1.0, starts, ends)
        assert np.array_equal(six.avar[:, cols], three.avar)
        assert np.array_equal(six.terms, three.terms) and np.array_equal(six.lags, three.lags)
        assert np.array_equal(three.avar, _packed_reference(part, starts, ends)[1])


def test_still_noise_shares_one_pass_for_one_clock() -> None:
    """Row getters on one clock: the rows of both sensors are read once, side by side, and the
    figures are those of the arrays."""
    session, _ = make_session(poses=14, seed=8, acc_rate=200.0, gyro_rate=200.0)
    result = imucal.calibrate(session)
    cal = result.calibrated
    whole = still_noise(cal, result.block_times)
    reads = []

    class Source:
        acc_unit = cal.acc_unit
        t_acc = t_gyro = cal.t_acc

        def acc(self, a, b):
            reads.append(("acc", a, b))
            return cal.acc[a:b] * 1.0

        def gyro(self, a, b):
            reads.append(("gyro", a, b))
            return cal.gyro[a:b] * 1.0

    rows = still_noise(Source(), result.block_times)
    assert [r[1:] for r in reads if r[0] == "acc"] == [r[1:] for r in reads if r[0] == "gyro"]
    for a, b in ((rows.accelerometer, whole.accelerometer), (rows.gyroscope, whole.gyroscope)):
        assert np.array_equal(a.curve.avar, b.curve.avar) and a.rate_hz == b.rate_hz
        assert a.per_axis("white") == b.per_axis("white")
