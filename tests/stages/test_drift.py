"""A bias that creeps during the session is measured and said (issue 27, slow drifts): a 20 mg
accelerometer ramp stayed one segment with no word; a gyroscope bias drift neither."""

from __future__ import annotations

import numpy as np
import pytest

import imucal
from imucal.stages import verdict as V
from imucal.stages.drift import gyroscope_drift
from imucal.synth import make_session


def _drift(r, code):
    found = [w for w in r.warnings if w.code == code]
    return found[0] if found else None


@pytest.mark.parametrize("seed", [0, 1])
def test_an_accelerometer_bias_ramp_is_said(seed):
    r = imucal.calibrate(make_session(poses=30, seed=seed, acc_drift=0.02)[0])
    assert len(r.segments) == 1  # a ramp is no step: the grouping keeps one segment
    w = _drift(r, "acc_bias_drift")
    assert w is not None, [x.code for x in r.warnings]
    size = float(w.message.split("about ")[1].split(" mg")[0])
    assert 16 <= size <= 24  # the 20 mg it was given
    assert "warm up" in w.message
    v = r.verdict
    assert v.level != V.GOOD
    assert "acc_bias_drift" in [v.code, *(c.code for c in v.caveats)]
    assert _drift(r, "gyro_bias_drift") is None


def test_a_gyroscope_bias_drift_is_said_and_judged():
    r = imucal.calibrate(make_session(poses=30, seed=0, gyro_drift=float(np.radians(1.0)))[0])
    w = _drift(r, "gyro_bias_drift")
    assert w is not None
    assert 0.8 <= float(w.message.split("about ")[1].split(" deg/s")[0]) <= 1.2
    assert r.verdict.level == V.CAVEATS and r.verdict.code == "gyro_bias_drift"
    assert r.verdict.next_step.startswith("let the sensor warm up")
    assert r.verdict.reason.startswith("the gyroscope's bias moved during the recording")
    assert "warm up" not in r.verdict.reason  # the advice is the next step, said once
    assert _drift(r, "acc_bias_drift") is None


@pytest.mark.parametrize("seed", [2, 21])
def test_a_steady_session_has_no_drift(seed):
    r = imucal.calibrate(make_session(poses=30, seed=seed)[0])
    assert {w.code for w in r.warnings}.isdisjoint({"acc_bias_drift", "gyro_bias_drift"})
    assert r.verdict.level == V.GOOD


def test_the_gyroscope_test_on_block_means_alone():
    # Forty still blocks of 200 samples, white noise 0.01 rad/s: steady, then a 0.02 rad/s ramp.
    rng = np.random.default_rng(5)
    t = np.arange(40 * 300) / 100.0
    blocks = np.array([[3.0 * k, 3.0 * k + 2.0] for k in range(40)])
    steady = 0.003 + rng.normal(0, 0.01, (len(t), 3))
    a = gyroscope_drift(steady, t, blocks, np.ones(3))
    assert a is not None and not a.drifting and a.p_value > 1e-3
    assert 0.5 < a.noise_ratio < 2  # white noise: the blocks scatter as their noise says
    ramp = steady + np.outer(t / t[-1], [0.02, 0.0, 0.0])
    b = gyroscope_drift(ramp, t, blocks, np.ones(3))
    assert b.drifting and b.p_value < 1e-10
    assert b.change[0] == pytest.approx(np.degrees(0.02) * (blocks[-1].mean() - blocks[0].mean())
                                        / t[-1], rel=0.05)
