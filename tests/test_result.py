"""What the Result derives for its readers, and the one convention for the still blocks."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import imucal
from imucal.numerics.windows import mask_of_runs, runs_of_true, samples_within
from imucal.stages.gyro import static_bias
from imucal.synth import make_session


@given(st.lists(st.booleans(), max_size=200))
def test_mask_of_runs_inverts_runs_of_true(bits):
    mask = np.array(bits, dtype=bool)
    np.testing.assert_array_equal(mask_of_runs(runs_of_true(mask), len(mask)), mask)


def test_samples_within_includes_both_ends():
    t = np.arange(10) / 4.0
    np.testing.assert_array_equal(samples_within(t, [[0.5, 1.25], [1.3, 1.5], [2.3, 5.0]]),
                                  [[2, 6], [6, 7], [10, 10]])


@pytest.fixture(scope="module")
def shared_clock():
    s, _ = make_session(poses=20, seed=4)  # the gyroscope on the accelerometer's clock
    assert np.array_equal(s.t_acc, s.t_gyro)
    return imucal.calibrate(s)


def test_one_still_convention_for_both_sensors(shared_clock):
    r = shared_clock
    # block_times hold each block's first and last sample: the samples inside them, ends
    # included, are the detector's blocks, on either sensor's clock.
    np.testing.assert_array_equal(samples_within(r.session.t_acc, r.block_times),
                                  r.detection.blocks)
    np.testing.assert_array_equal(r.gyro_blocks, r.detection.blocks)
    np.testing.assert_array_equal(r.gyro_still, r.acc_still)
    assert r.acc_still.sum() == np.sum(np.diff(r.detection.blocks, axis=1))
    # and the gyroscope bias is measured on exactly those samples
    bias, how = static_bias(r.session.gyro, r.session.t_gyro, r.block_times, "all")
    np.testing.assert_allclose(bias, r.session.gyro[r.gyro_still].mean(axis=0), rtol=1e-12)
    np.testing.assert_array_equal(r.segments[0].gyro.static_bias, bias)
    assert f"({int(r.gyro_still.sum())} samples)" in how


def test_derived_arrays(shared_clock):
    r = shared_clock
    s = r.session
    np.testing.assert_allclose(r.raw_acc_norm, np.linalg.norm(s.acc, axis=1), rtol=1e-15)
    np.testing.assert_array_equal(r.raw_gyro_norm, np.linalg.norm(s.gyro, axis=1))  # rad/s
    np.testing.assert_array_equal(r.block_middles, r.block_times.mean(axis=1))
    sweep, lc = r.whole.sweep, r.whole.lcurve
    assert sweep.params.shape == (len(lc.lambdas), 9)
    assert sweep.block_norm_error_mg.shape == (len(lc.lambdas), len(r.detection.blocks))
    # At the corner the sweep's solution is the calibration's when the corner's refit from
    # every start lands where the continuation did; its block errors are the quality's.
    c = lc.corner
    np.testing.assert_allclose(sweep.params[c], r.whole.params, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(sweep.block_norm_error_mg[c], r.quality.block_norm_error_mg,
                               rtol=1e-5, atol=1e-6)
    assert sweep.static_norm_rms_mg[c] == pytest.approx(r.quality.static_norm_rms_mg.after,
                                                        rel=1e-5)
    # Small lambdas fit the blocks at least as well as the largest, which holds the prior.
    assert sweep.static_norm_rms_mg[0] < sweep.static_norm_rms_mg[-1]
    tr = r.segments[0].acc.trace_params
    assert tr.shape == (len(r.segments[0].acc.report.trace_cost), 9)
    np.testing.assert_allclose(tr[-1], r.segments[0].acc.params, rtol=1e-12)
    g = r.segments[0].gyro
    np.testing.assert_allclose(g.trace_params[-1], g.params, rtol=1e-12)
    np.testing.assert_array_equal(g.trace_bias[-1], g.model.b)
    np.testing.assert_allclose(g.trace_params[0][6:9], [1, 1, 1])  # it starts at the prior


def test_raw_gyro_norm_in_counts_goes_through_the_nominal():
    s, truth = make_session(poses=30, seed=2, gyro_unit="counts")
    r = imucal.calibrate(s)
    g = r.segments[0].gyro
    np.testing.assert_allclose(r.raw_gyro_norm,
                               np.linalg.norm((s.gyro - g.model.b) * g.nominal_scale, axis=1))
    # near the calibrated magnitude while turning (scales within a few percent of nominal)
    moving = r.calibrated.gyro_norm > 0.5
    ratio = r.raw_gyro_norm[moving] / r.calibrated.gyro_norm[moving]
    assert np.median(ratio) == pytest.approx(1.0, abs=0.1)
