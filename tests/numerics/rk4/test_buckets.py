"""imucal.numerics.rk4.buckets: every interval in exactly one bucket, laid out as direct
indexing would give it."""

import numpy as np
import pytest

from imucal.numerics.rk4.buckets import BUCKET_OVERHEAD_STEPS, lay_out, length_buckets


def _padded_steps(n_steps, buckets):
    return sum(len(b) * max(n_steps[b].max(), 1) - n_steps[b].sum() for b in buckets)


@pytest.mark.parametrize("seed", range(4))
def test_every_interval_is_in_exactly_one_bucket(seed):
    rng = np.random.default_rng(seed)
    n_steps = rng.integers(0, 20000, 300)
    buckets = length_buckets(n_steps)
    np.testing.assert_array_equal(np.sort(np.concatenate(buckets)), np.arange(300))
    for b in buckets:
        assert np.all(np.diff(b) > 0)  # indices in order within a bucket
    tops = [n_steps[b].max() for b in buckets]
    assert tops == sorted(tops, reverse=True)  # longest first
    # Buckets save padding: never more than one bucket for everything would pad.
    assert _padded_steps(n_steps, buckets) <= _padded_steps(n_steps, [np.arange(300)])


def test_equal_lengths_share_one_bucket():
    assert len(length_buckets(np.full(50, 123))) == 1


def test_many_short_intervals_do_not_pad_to_one_long_one():
    n_steps = np.r_[20000, np.full(1000, 10)]
    buckets = length_buckets(n_steps)
    assert len(buckets) == 2 and buckets[0].tolist() == [0]


def test_a_few_slightly_shorter_intervals_share_the_bucket():
    # splitting would save 3 x 300 padded steps, far below what a bucket of its own costs
    assert 3 * 300 < BUCKET_OVERHEAD_STEPS
    assert len(length_buckets(np.array([1000, 700, 700, 700]))) == 1


def test_no_intervals_no_buckets():
    assert length_buckets(np.zeros(0, np.int64)) == []


def test_lay_out_indexes_every_step_of_every_interval():
    rng = np.random.default_rng(7)
    t = np.cumsum(rng.uniform(0.005, 0.015, 200))
    starts = np.array([5, 50, 120, 199])
    n_steps = np.array([10, 3, 0, 0])
    b = lay_out(t, starts, n_steps, np.arange(4))
    L = 10
    assert b.i0.shape == b.valid.shape == (L + 1, 4) and b.dt.shape == b.dt2.shape == (L, 4)
    for k, (s, n) in enumerate(zip(starts, n_steps)):
        np.testing.assert_array_equal(b.i0[:n + 1, k], np.arange(s, s + n + 1))
        assert b.valid[:n + 1, k].all() and not b.valid[n + 1:, k].any()
        np.testing.assert_array_equal(b.dt[:n, k], np.diff(t[s:s + n + 1]))
        np.testing.assert_array_equal(b.dt[n:, k], 0.0)  # padding: identity steps
    np.testing.assert_array_equal(b.dt2, b.dt * b.dt)
    idx, i0, valid, dt, dt2 = b  # unpacks like the tuple it was
    assert idx is b.idx and dt is b.dt
