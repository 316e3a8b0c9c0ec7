"""Reading a signal a block of rows at a time (imucal/numerics/rows.py): what numpy's call on the
whole array gives, through slices and gathers only (tests/row_only.py)."""

from __future__ import annotations

import numpy as np
import pytest
from row_only import RowOnly

from imucal.numerics.rows import (
    RowRange,
    column_extremes,
    pairwise_sum,
    rows_where,
    search_sorted,
    strictly_increasing,
    value_at,
)


@pytest.mark.parametrize("n, leaf", [(1, 4), (7, 4), (129, 16), (100_003, 1000),
                                     (3_000_017, 1 << 18)])
def test_pairwise_sum_is_numpys_to_the_bit(n, leaf) -> None:
    rng = np.random.default_rng(n)
    a = np.abs(rng.normal(size=n)) * rng.lognormal(0.0, 3.0, n)
    got = pairwise_sum(lambda i, j: a[i:j], n, leaf)
    assert got == float(np.add.reduce(a))
    assert got / n == float(np.mean(a))


@pytest.mark.parametrize("side", ["left", "right"])
def test_search_sorted_through_slices(side) -> None:
    rng = np.random.default_rng(1)
    t = np.sort(np.round(rng.uniform(0.0, 100.0, 50_000), 2))  # ties
    values = np.concatenate([[-1.0, 0.0, t[0], t[-1], 200.0], rng.uniform(-5, 105, 300),
                             t[rng.integers(0, len(t), 50)]])
    got = search_sorted(RowOnly(t), values, side=side, rows=997)
    np.testing.assert_array_equal(got, np.searchsorted(t, values, side=side))


def test_small_reads_of_a_clock_and_a_signal() -> None:
    t = np.arange(10_000) / 100.0
    assert strictly_increasing(RowOnly(t), rows=333)
    bumped = t.copy()
    bumped[5000] = bumped[4999]
    assert not strictly_increasing(RowOnly(bumped), rows=333)
    assert value_at(RowOnly(t), -1) == t[-1] and value_at(RowOnly(t), 3) == t[3]
    x = np.random.default_rng(2).normal(size=(10_000, 3))
    lo, hi = column_extremes(RowOnly(x), rows=333)
    np.testing.assert_array_equal(lo, x.min(axis=0))
    np.testing.assert_array_equal(hi, x.max(axis=0))
    kept = rows_where(RowOnly(x), lambda a, b: (t[a:b] >= 20.0) & (t[a:b] < 21.0), rows=333)
    np.testing.assert_array_equal(kept, x[(t >= 20.0) & (t < 21.0)])
    r = RowRange(RowOnly(x), 100, 5100)
    assert len(r) == 5000 and r.shape == (5000, 3)
    np.testing.assert_array_equal(r[10:20], x[110:120])
