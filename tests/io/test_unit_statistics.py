"""The unit guesses' statistics, computed a block of rows at a time, are numpy's to the bit on
the signals that break shortcuts: ties, heavy tails, NaN, inf, zeros, values whose squares
underflow or overflow (the median norm's screen by sums of squares must step aside there)."""

from __future__ import annotations

import numpy as np
import pytest

from imucal.io.units import _abs_median, _integer_like, _median_row_norm, abs_median_p995

KINDS = ["normal", "ties", "tails", "tiny", "huge", "inf", "nan", "counts", "zeros",
         "subnormal", "gaps"]


def _signal(kind: str, n: int, rng: np.random.Generator) -> np.ndarray:
    x = rng.normal(0.0, 1.0, (n, 3))
    if kind == "ties":
        x = np.round(x * 4)
    elif kind == "tails":
        x = rng.standard_t(2, (n, 3))
    elif kind == "tiny":
        x *= 1e-120
    elif kind == "huge":
        x *= 1e130
    elif kind == "inf":
        x[rng.integers(0, n, 5)] = np.inf
    elif kind == "nan":
        x[rng.integers(0, n), 1] = np.nan
    elif kind == "counts":
        x = np.round(rng.normal(3e4, 40.0, (n, 3)))
    elif kind == "zeros":
        x[: n // 2] = 0.0
    elif kind == "subnormal":
        x *= 1e-160
    elif kind == "gaps":  # counts with a few interpolated samples
        x = np.round(rng.normal(3e4, 40.0, (n, 3)))
        x[rng.integers(0, n, n // 200)] += 0.5
    return x


def _same(a: float, b: float) -> bool:
    return bool(np.array_equal(np.array([a]), np.array([b]), equal_nan=True))


@pytest.mark.parametrize("kind", KINDS)
def test_unit_statistics_are_numpys(kind: str) -> None:
    rng = np.random.default_rng(KINDS.index(kind))
    for n in (80_001, 80_000):  # odd and even counts: one rank or the mean of two
        x = _signal(kind, n, rng)
        magnitude = np.abs(x)
        assert _same(_median_row_norm(x, small=0), float(np.median(np.linalg.norm(x, axis=1))))
        assert _same(_abs_median(x, small=0), float(np.median(magnitude)))
        got = abs_median_p995(x, small=0)
        want = (float(np.median(magnitude)), float(np.percentile(magnitude, 99.5)))
        assert _same(got[0], want[0]) and _same(got[1], want[1])
        assert _integer_like(x, rows=4096) == bool(np.mean(x == np.round(x)) >= 0.99)


def test_integer_like_is_numpys_at_the_threshold() -> None:
    """Exactly 99 % integers passes, one fewer does not: a count over n, as numpy's mean."""
    x = np.zeros((10_000, 1))
    x[:100] = 0.5
    assert _integer_like(x, rows=333) and bool(np.mean(x == np.round(x)) >= 0.99)
    x[100] = 0.5
    assert not _integer_like(x, rows=333)
    assert not _integer_like(np.zeros((0, 3)))
