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
    still = mask_of_runs(r.detection.blocks, len(r.session.t_gyro))
    # and the gyroscope bias is measured on exactly those samples
    bias, how = static_bias(r.session.gyro, r.session.t_gyro, r.block_times, "all")
    np.testing.assert_allclose(bias, r.session.gyro[still].mean(axis=0), rtol=1e-12)
    np.testing.assert_array_equal(r.segments[0].gyro.static_bias, bias)
    assert f"({int(still.sum())} samples)" in how
