"""The compiled Allan loops against the numpy they replace, to the bit."""

from __future__ import annotations

import numpy as np
import pytest

from imucal.numerics.allan_kernels import centred_runs, kept_sum


@pytest.mark.parametrize("seed", range(6))
def test_kept_sum_is_the_zeroed_einsum(seed: int) -> None:
    rng = np.random.default_rng(seed)
    k = (3, 6)[seed % 2]
    n, m, o = 20_000, int(rng.integers(1, 600)), int(rng.integers(0, 1000))
    S = np.cumsum(rng.normal(size=(n, k)) * 10.0 ** rng.integers(-4, 4), axis=0)
    lo, hi = o, o + n - 2 * m
    cuts = np.sort(rng.choice(np.arange(lo, hi), 16, replace=False))
    ka, kb = cuts[::2].astype(np.int64), cuts[1::2].astype(np.int64)
    # numpy: the whole slice's second differences, the points outside [ka, kb) zeroed
    d = np.empty((hi - lo, k))
    np.multiply(S[m:m + hi - lo], 2.0, out=d)
    np.subtract(S[2 * m:2 * m + hi - lo], d, out=d)
    d += S[:hi - lo]
    keep = np.zeros(hi - lo, bool)
    for a, b in zip(ka, kb):
        keep[a - lo:b - lo] = True
    d[~keep] = 0.0
    want = np.einsum("ij,ij->j", d, d)
    got = kept_sum(S, o, m, ka, kb)
    assert np.array_equal(got, want)


@pytest.mark.parametrize("seed", range(6))
def test_centred_runs_is_the_numpy_centring(seed: int) -> None:
    rng = np.random.default_rng(seed)
    k = (3, 6)[seed % 2]
    xs = rng.normal(size=(50_000, k)) * 0.01 + rng.normal(size=k) * 9.81
    cuts = np.sort(rng.choice(len(xs), 20, replace=False)).astype(np.int64)
    s, e = cuts[::2], cuts[1::2]
    want = np.concatenate([xs[a:b] - np.einsum("ij->j", xs[a:b]) / (b - a)
                           for a, b in zip(s, e)])
    assert np.array_equal(want, np.concatenate([xs[a:b] - xs[a:b].mean(axis=0)
                                                for a, b in zip(s, e)]))
    out = np.empty((int(np.sum(e - s)), k))
    centred_runs(xs, s, e, out)
    assert np.array_equal(out, want)
