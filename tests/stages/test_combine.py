"""The low-range and high-range accelerometers combined (method.md M18): the blend, the step,
the clip levels and which triad is which."""

from __future__ import annotations

import numpy as np

from imucal.stages.combine import BAND, choose_low, clip_levels, combine, weights


def test_blend_is_the_low_triad_below_the_band_the_high_above_and_continuous():
    u = np.linspace(0.0, 1.0, 20001)
    w = weights(u)
    assert np.all(w[u <= BAND[0]] == 0) and np.all(w[u >= BAND[1]] == 1)
    assert np.all(np.diff(w) >= 0)
    assert np.max(np.abs(np.diff(w))) < 1e-3  # no jump: 1.5 / (band width * 20000) at most
    rng = np.random.default_rng(0)
    low = rng.normal(0, 1, (len(u), 3))
    d = np.array([0.004, -0.002, 0.001])  # a 4.6 mg step between the triads
    out, step = combine(low, low + d, u, 1.0)
    below, above = u < BAND[0], u > BAND[1]
    np.testing.assert_array_equal(out[below], low[below])
    np.testing.assert_allclose(out[above], low[above] + d, atol=1e-15)
    np.testing.assert_allclose(step.vector_mg, d * 1e3, atol=1e-9)
    assert step.samples == int(((u >= BAND[0]) & (u <= BAND[1])).sum())
    # A high-range triad without a sample there: the low one, and no step where none is.
    out, step = combine(low, np.full_like(low, np.nan), u, 1.0)
    np.testing.assert_array_equal(out, low)
    assert step is None


def test_clip_levels_found_and_which_is_low():
    rng = np.random.default_rng(1)
    t = np.arange(4000) / 100.0  # a slow swing to 3 g: a 2 g part sits flat at its limits
    f = 3.0 * np.sin(2 * np.pi * 0.5 * t[:, None] + np.array([0.0, 2.0, 4.0]))
    low = np.clip(f + rng.normal(0, 0.003, f.shape), -2.0, 2.0)
    high = f + rng.normal(0, 0.006, f.shape)
    levels = clip_levels(low, "g", None)
    np.testing.assert_array_equal(levels.lo, [-2, -2, -2])
    np.testing.assert_array_equal(levels.hi, [2, 2, 2])
    assert levels.how == "found in the data"
    u = levels.nearness(low)
    assert np.all(u[np.any(np.abs(low) == 2.0, axis=1)] == 1.0)
    assert choose_low(("a", "a2"), (low, high), ("g", "g"), (None, None)).low == 0
    assert choose_low(("a", "a2"), (high, low), ("g", "g"), (None, None)).low == 1
    # In m/s^2 the level is read in g; stated ranges decide before the data.
    assert choose_low(("a", "a2"), (high, low * 9.80665), ("g", "m/s^2"), (None, None)).low == 1
    assert choose_low(("a", "a2"), (low, high), ("g", "g"), (16.0, 4.0)).low == 1
    same = choose_low(("a", "a2"), (high, high), ("g", "g"), (None, None))
    assert same.low is None and "neither" in same.why
    # Nothing clipped: the stated range gives the limits, in the raw unit.
    stated = clip_levels(high * 9.80665, "m/s^2", 8.0)
    np.testing.assert_allclose(stated.hi, 8 * 9.80665)
    assert stated.how == "stated" and clip_levels(high, "g", None) is None
