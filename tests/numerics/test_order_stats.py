"""ranked_values against np.sort: the values at the ranks asked for, to the bit."""

from __future__ import annotations

import numpy as np
import pytest

from imucal.numerics.order_stats import ranked_values


def _chunks(v: np.ndarray, size: int):
    return lambda: (v[i:i + size] for i in range(0, len(v), size))


def _values(rng: np.random.Generator, kind: str, n: int) -> np.ndarray:
    if kind == "normal":
        return rng.normal(size=n)
    if kind == "few levels":
        return np.round(rng.normal(size=n) * 3)
    if kind == "integers":
        return rng.integers(0, 3, n).astype(float)
    return rng.standard_t(1, n)


@pytest.mark.parametrize("kind", ["normal", "few levels", "integers", "heavy tails"])
def test_ranks_are_np_sorts(kind):
    rng = np.random.default_rng(11)
    for _ in range(60):
        n = int(rng.integers(50, 4000))
        v = _values(rng, kind, n)
        ranks = sorted(rng.integers(0, n, 2).tolist())
        got = ranked_values(_chunks(v, int(rng.integers(1, 600))), n, [ranks, [n // 2]],
                            sample=int(rng.integers(5, n + 1)))
        if got is None:  # a bracket missed or held too much: the caller sorts a copy
            continue
        s = np.sort(v)
        assert got == [[float(s[r]) for r in ranks], [float(s[n // 2])]]


def test_a_clocks_few_steps_are_counted_not_kept():
    """Every value equal to one the sample holds is counted: nothing is kept, and the answer
    is still exact (the brackets never fall back on ties)."""
    v = np.tile([0.001, 0.001, 0.001, 0.002], 50_000)
    got = ranked_values(_chunks(v, 4096), len(v), [[len(v) // 2 - 1, len(v) // 2]], 1000)
    assert got == [[0.001, 0.001]]


def test_nan_makes_the_statistics_nan():
    v = np.arange(10_000, dtype=float)
    v[1234] = np.nan
    got = ranked_values(_chunks(v, 1000), len(v), [[5000]], sample=10_000)
    assert np.isnan(got[0][0])


@pytest.mark.parametrize("kind", ["clock", "two steps", "mode below the ranks"])
def test_a_dominant_value_counted_first_gives_np_sorts_ranks(kind):
    """Values a quarter or more of the sample equals are counted by one comparison before the
    bracket and the search: the ranks are still np.sort's, and the median and quantiles
    interpolated from them numpy's, to the bit."""
    rng = np.random.default_rng(5)
    for _ in range(30):
        n = int(rng.integers(2000, 40_000))
        if kind == "clock":  # one step, a jitter of an ulp or two, some doubled steps
            v = np.diff(np.arange(n + 1) / 1000.0)
            v[rng.integers(0, n, n // 40)] *= 2
        elif kind == "two steps":
            v = np.where(rng.random(n) < 0.55, 0.01, 0.0025)
        else:
            v = np.concatenate([np.zeros(n // 3), rng.normal(size=n - n // 3)])
            rng.shuffle(v)
        ranks = sorted(rng.integers(0, n, 2).tolist())
        mid = [(n - 1) // 2, n // 2]
        got = ranked_values(_chunks(v, int(rng.integers(100, 5000))), n, [ranks, mid],
                            sample=int(rng.integers(200, n)))
        if got is None:
            continue
        s = np.sort(v)
        assert got == [[float(s[r]) for r in ranks], [float(s[r]) for r in mid]]
        m0, m1 = got[1]
        assert (m1 if n % 2 else float(np.mean([m0, m1]))) == float(np.median(v))
