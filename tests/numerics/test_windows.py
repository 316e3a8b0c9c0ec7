"""imucal.numerics.windows against direct sums (sliding windows, loops, math.fsum) and numpy."""

import math

import numpy as np
import pytest
from numpy.lib.stride_tricks import sliding_window_view

from imucal.numerics.windows import (
    block_means,
    chunked_window_sums,
    median_inplace,
    moving_sum,
    segment_sums,
)


def _direct_moving_sum(y: np.ndarray, w: int) -> np.ndarray:
    """Centred window (w // 2 before), ends mirrored about the end samples (numpy's 'reflect')."""
    left = w // 2
    pad = np.pad(y, ((0, 0), (left, w - 1 - left)), mode="reflect")
    return sliding_window_view(pad, w, axis=1).sum(axis=-1)


@pytest.mark.parametrize("n, w", [(1000, 1), (1000, 2), (1000, 7), (1000, 50), (257, 101)])
def test_moving_sum_is_the_windowed_sum(n, w):
    y = np.random.default_rng(n + w).normal(size=(2, n))
    np.testing.assert_allclose(moving_sum(y, w), _direct_moving_sum(y, w), atol=1e-12)


@pytest.mark.parametrize("chunk, group", [(16, 1), (16, 3), (40, 2), (1000, 8)])
def test_moving_sum_across_chunks_and_groups(chunk, group):
    # Small chunks: windows cross chunk and group boundaries everywhere.
    y = np.random.default_rng(chunk).normal(size=(3, 1234))
    got = moving_sum(y, 11, chunk=chunk, group=group)
    np.testing.assert_allclose(got, _direct_moving_sum(y, 11), atol=1e-12)


@pytest.mark.parametrize("n", [1, 2, 3, 5])
def test_moving_sum_of_a_signal_shorter_than_half_a_window(n):
    y = np.arange(1.0, n + 1)[None, :]
    got = moving_sum(y, 11)
    if n == 1:
        np.testing.assert_allclose(got, [[11.0]])  # one sample, repeated across the window
    else:
        idx = np.arange(-5, 6)[None, :] + np.arange(n)[:, None]
        # mirror about the end samples, again and again (the signal is shorter than the pad)
        period = 2 * (n - 1)
        idx = np.abs((idx + period) % period)
        idx = np.where(idx > n - 1, period - idx, idx)
        np.testing.assert_allclose(got[0], y[0][idx].sum(axis=1))


def test_moving_sum_writes_into_out():
    y = np.random.default_rng(3).normal(size=(2, 500))
    out = np.empty((2, 500))
    assert moving_sum(y, 9, out=out) is out
    np.testing.assert_allclose(out, _direct_moving_sum(y, 9), atol=1e-12)


def test_moving_sum_keeps_a_still_windows_digits_on_a_long_offset_signal():
    # A still sensor at a large offset: the window sums must keep the noise's digits, which a
    # difference of two running totals over 2e6 samples would lose.
    rng = np.random.default_rng(5)
    y = (1e4 + 1e-3 * rng.normal(size=2_000_000))[None, :]
    got = moving_sum(y, 101)
    for i in (150, 1_000_000, 1_999_000):
        exact = math.fsum(y[0, i - 50:i + 51])
        assert abs(got[0, i] - exact) < 1e-8  # |sum| ~ 1e6: about 1e-14 relative


@pytest.mark.parametrize("w, m, b", [(3, 20, 4), (5, 50, 5), (1, 10, 3), (4, 30, 100)])
def test_chunked_window_sums_are_the_sums_of_each_window(w, m, b):
    z = np.random.default_rng(w * m).normal(size=(2, m + w - 1))
    ref = sliding_window_view(z, w, axis=1).sum(axis=-1)[:, :m]
    np.testing.assert_allclose(chunked_window_sums(z, w, m, b), ref, atol=1e-12)


@pytest.mark.parametrize("n", [1, 2, 7, 10])
def test_median_inplace_is_the_median(n):
    a = np.random.default_rng(n).normal(size=n)
    assert median_inplace(a.copy()) == np.median(a)


def test_median_inplace_of_nothing_is_nan():
    assert math.isnan(median_inplace(np.zeros(0)))


def _loop_sums(x, starts, ends):
    return np.array([x[s:e].sum(axis=0) if e > s else np.zeros(x.shape[1:])
                     for s, e in zip(starts, ends)])


@pytest.mark.parametrize("starts, ends", [
    ([0, 10, 40], [5, 30, 100]),      # sorted and apart, the last to the end
    ([3, 3, 50], [3, 20, 60]),        # an empty range
    ([0, 10], [20, 30]),              # overlapping: the cumulative-sum path
    ([50, 0], [60, 10]),              # out of order
    ([0], [100]),                     # the whole signal
])
def test_segment_sums_are_the_sums_of_each_range(starts, ends):
    x = np.random.default_rng(1).normal(size=(100, 3))
    got = segment_sums(x, np.array(starts), np.array(ends))
    np.testing.assert_allclose(got, _loop_sums(x, starts, ends), atol=1e-12)


def test_segment_sums_of_no_ranges_and_of_one_column():
    x = np.arange(10.0)
    assert segment_sums(x, np.zeros(0, int), np.zeros(0, int)).shape == (0,)
    np.testing.assert_array_equal(segment_sums(x, np.array([2, 5]), np.array([4, 10])),
                                  [5.0, 35.0])


def test_segment_sums_keep_full_precision_on_an_offset_signal():
    rng = np.random.default_rng(2)
    x = (1e6 + rng.normal(size=(400_000, 1)))
    got = segment_sums(x, np.array([399_000]), np.array([399_100]))[0, 0]
    assert abs(got - math.fsum(x[399_000:399_100, 0])) < 1e-6


def test_block_means_are_the_means_of_each_block():
    x = np.random.default_rng(4).normal(size=(200, 3))
    blocks = np.array([[0, 10], [20, 21], [50, 200]])
    ref = np.array([x[s:e].mean(axis=0) for s, e in blocks])
    np.testing.assert_allclose(block_means(x, blocks), ref, atol=1e-15)
    assert block_means(x, np.zeros((0, 2), int)).shape == (0, 3)
