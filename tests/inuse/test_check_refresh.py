"""A calibration in use (method.md §10): the still moments of everyday use, the check of a
stored calibration against them and its refresh, on synthetic everyday use with known drift
(imucal.inuse.everyday) and on the BROAD tapping trial."""

from __future__ import annotations

import numpy as np
import pytest

from imucal.inuse.check import CANNOT_TELL, DRIFTED, HOLDS, Stored, check
from imucal.inuse.everyday import Drift, make_everyday
from imucal.inuse.refresh import refresh
from imucal.models import SensorModel
from imucal.stages.apply import Calibration, SegmentModels

# What a calibration run stores (§5): a held-out still-norm error of 0.3 mg, and the synthetic
# sensor's own white noise density (3 mg per sample at 100 Hz).
STORED = Stored(static_norm_mg=0.3, acc_noise_density=0.003 / 10.0)
GYRO_DRIFT = np.radians([0.3, -0.25, 0.2])  # rad/s


def stored_calibration(truth) -> Calibration:
    return Calibration(segments=(SegmentModels(0.0, 0.0, truth.stored_acc, truth.stored_gyro),),
                       acc_unit_raw="g", acc_unit="g", g=1.0, gyro_unit_raw="rad/s")


@pytest.mark.parametrize("activity", ["walk", "jumps", "desk"])
def test_a_calibration_that_holds_is_said_to_hold_on_20_of_20_seeds(activity):
    levels = []
    for seed in range(20):
        session, truth = make_everyday(activity, minutes=10, seed=100 + seed)
        levels.append(check(stored_calibration(truth), STORED, session).level)
    assert levels.count(HOLDS) == 20, levels  # measured: 20 of 20 for each activity


@pytest.mark.parametrize("activity", ["walk", "jumps", "desk"])
def test_a_drifted_gyroscope_bias_is_named_and_refreshed_within_0_05_deg_s(activity):
    errors = []
    for seed in range(5):
        session, truth = make_everyday(activity, minutes=10, seed=seed,
                                       drift=Drift(gyro_bias=GYRO_DRIFT))
        cal = stored_calibration(truth)
        c = check(cal, STORED, session)
        assert c.level == DRIFTED and c.exit_code == 1
        acc, gyro = c.parts
        assert gyro.level == DRIFTED and acc.level == HOLDS
        # which parameters: all three axes moved by more than 0.1 deg/s
        assert {e.parameter for e in gyro.changes} == {"b_x", "b_y", "b_z"}
        moved = np.array([e.change for e in gyro.changes])
        np.testing.assert_allclose(moved, GYRO_DRIFT, atol=np.radians(0.05))
        r = refresh(cal, STORED, session)
        err = np.degrees(np.abs(r.gyro.b - truth.gyro.b))
        assert err.max() < 0.05, err  # measured: at most 0.010 deg/s over 20 seeds
        # each still moment of 3 s or more on its own (M10): the sway's tilt removed
        m = r.check.moments
        long = m.durations >= 3.0
        assert long.sum() >= 5
        truth_rate = truth.stored_gyro.matrix @ GYRO_DRIFT  # what the stored model leaves
        per_moment = np.degrees(np.abs(m.rate[long] - truth_rate))
        errors.append(per_moment.ravel())
    # measured over these 5 seeds (moment-axes): walk 100 %, jumps 99.7 %, desk 100 % within
    # 0.05 deg/s; the worst 0.061 (a jumper's sway about the vertical, which M10 cannot see)
    errors = np.concatenate(errors)
    assert np.mean(errors < 0.05) >= 0.99 and errors.max() < 0.08
    assert np.median(errors) < 0.015


def test_without_the_tilt_correction_the_sway_spoils_the_bias():
    """M10's correction matters: the mean rate over a moment of a swaying person, taken as the
    bias, is off by up to a tenth of a degree per second."""
    from imucal.inuse import moments as mod

    session, truth = make_everyday("walk", minutes=10, seed=1)
    acc = truth.stored_acc.apply(session.acc)
    gyro = truth.stored_gyro.apply(session.gyro)
    m = mod.find_moments(session.acc, acc, session.t_acc, gyro, session.t_gyro, 1.0, 0.003,
                         100.0)
    plain = np.array([gyro[a:b].mean(axis=0) for a, b in m.blocks])
    assert np.degrees(np.abs(plain)).max() > 0.1  # the sway's net turn over the moment
    assert np.degrees(np.abs(m.rate)).max() < 0.06  # M10


def test_a_drifted_accelerometer_is_named_refreshed_and_the_rest_kept_as_stored():
    drift = Drift(acc_bias=np.array([0.010, -0.005, 0.008]),
                  acc_scale=np.array([0.003, 0.0, -0.004]))
    session, truth = make_everyday("jumps", minutes=10, seed=3, drift=drift)
    cal = stored_calibration(truth)
    c = check(cal, STORED, session)
    acc, gyro = c.parts
    assert acc.level == DRIFTED and gyro.level == HOLDS and c.exit_code == 1
    assert acc.low > acc.limit  # the interval's lower end beyond max(2 mg, twice expected)
    assert {"b_x", "b_y", "b_z"} <= {e.parameter for e in acc.changes}
    r = refresh(cal, STORED, session)
    assert r.check.moments.count >= 20  # 20 moments and more, 0.3 g on both sides of each axis
    assert r.check.acc_fit.covered.all()
    np.testing.assert_allclose(r.acc.b, truth.acc.b, atol=0.5e-3)  # measured: < 0.15 mg
    np.testing.assert_allclose(r.acc.K, truth.acc.K, rtol=5e-4)
    assert r.norm_before_mg > 5 and r.norm_after_mg < 3.0  # GGIR's best cohort: 3.0 mg
    # unchanged parameters stay exactly as stored: misalignments, the whole gyroscope but b
    assert np.array_equal(r.acc.T, truth.stored_acc.T)
    assert np.array_equal(r.gyro.T, truth.stored_gyro.T)
    assert np.array_equal(r.gyro.K, truth.stored_gyro.K)


def test_a_refresh_touches_only_the_axes_the_moments_cover():
    """On a desk lying only on +-z (no moment reads 0.3 g along x or y), x's and y's bias and
    scale stay as stored; z's are refreshed."""
    session, truth = make_everyday("desk", minutes=10, seed=2,
                                   drift=Drift(acc_bias=np.array([0.0, 0.0, 0.01])))
    cal = stored_calibration(truth)
    full = check(cal, STORED, session).moments
    u = full.cal_mean
    keep = np.abs(u[:, 2]) > 0.9  # the moments on +-z
    assert keep.sum() >= 6 and (u[keep, 2] > 0).any() and (u[keep, 2] < 0).any()
    from imucal.inuse.estimate import fit_acc

    sub = _only(full, keep)
    fit = fit_acc(cal.segments[0].acc, sub, 1.0, 0.3e-3, "g")
    assert fit.covered.tolist() == [False, False, True]
    assert {e.parameter for e in fit.estimates} == {"b_z", "s_z"}
    assert np.array_equal(fit.model.b[:2], truth.stored_acc.b[:2])
    assert np.array_equal(fit.model.K[:2], truth.stored_acc.K[:2])
    assert abs(fit.model.b[2] - truth.acc.b[2]) < 0.5e-3


def _only(m, keep):
    import dataclasses

    return dataclasses.replace(m, blocks=m.blocks[keep], times=m.times[keep], n=m.n[keep],
                               raw_mean=m.raw_mean[keep], cal_mean=m.cal_mean[keep],
                               norm_var=m.norm_var[keep], rate=m.rate[keep],
                               rate_se=m.rate_se[keep])


@pytest.mark.parametrize("activity", ["walk", "jumps", "desk"])
def test_taps_and_typing_make_no_still_moments(activity):
    """Over 10 seeds, hundreds of taps (bursts 0.3-1.2 s apart while held, single ones on the
    desk) and typing's vibration: no moment holds one, and none reaches past a real rest by
    more than 0.35 s (the minimum-jerk start of a pick-up from the desk, under a degree of
    tilt by then: measured at most 0.31 s)."""
    taps = 0
    for seed in range(10):
        session, truth = make_everyday(activity, minutes=10, seed=200 + seed)
        m = check(stored_calibration(truth), STORED, session).moments
        taps += len(truth.taps)
        assert m.count > 5
        for a, b in m.times:
            assert not np.any((truth.taps >= a - 0.02) & (truth.taps < b))
            assert not np.any((truth.disturbed[:, 0] < b) & (truth.disturbed[:, 1] > a))
            overlap = np.minimum(b, truth.still[:, 1]) - np.maximum(a, truth.still[:, 0])
            k = int(np.argmax(overlap))
            assert truth.still[k, 0] - a < 0.35 and b - truth.still[k, 1] < 0.35
    assert taps > 40


def test_too_few_moments_or_orientations_cannot_tell():
    session, truth = make_everyday("walk", minutes=1, seed=0)  # one rest, then carried
    c = check(stored_calibration(truth), STORED, session)
    assert c.level == CANNOT_TELL and c.exit_code == 2
    assert "too few still moments" in c.reason
    # a desk in one face only: many moments, one orientation
    session, truth = make_everyday("desk", minutes=10, seed=0)
    cal = stored_calibration(truth)
    first = session.t_acc < 40.0  # the first rest only, cut by typing into several moments
    one = type(session)(acc=session.acc[first], t_acc=session.t_acc[first],
                        gyro=session.gyro[first], t_gyro=session.t_gyro[first])
    c = check(cal, STORED, one)
    acc, gyro = c.parts
    assert c.moments.count >= 1 and c.moments.orientations == 1
    assert acc.level == CANNOT_TELL and gyro.level == HOLDS and c.level == CANNOT_TELL


def test_the_broad_tapping_trial_gives_no_moment_while_it_moves(shared_data):
    """BROAD trial 24: 2 minutes of rotation with finger taps between still phases: every
    still moment found lies in the still phases (the reference's ``movement`` false)."""
    import h5py

    import imucal

    path = shared_data / "broad" / "24_disturbed_tapping_A.hdf5"
    session = imucal.load_session(path)
    ident = SensorModel(T=np.eye(3), K=np.ones(3), b=np.zeros(3))
    cal = Calibration(segments=(SegmentModels(0.0, 0.0, ident, ident),),
                      acc_unit_raw="m/s^2", acc_unit="m/s^2", g=9.80665,
                      gyro_unit_raw="rad/s")
    m = check(cal, Stored(), session).moments
    with h5py.File(path) as f:
        moving = np.asarray(f["movement"]).ravel().astype(bool)
    assert m.count >= 2  # the two still phases, 44 s and 36 s
    for a, b in m.blocks:
        assert not moving[a:b].any()


def test_a_recording_shorter_than_a_moment_cannot_tell():
    """A log of a few samples (the shared PX4 sample holds 6 at 1 Hz) has no moment: cannot
    tell, not an error."""
    session, truth = make_everyday("walk", minutes=1, seed=0)
    tiny = type(session)(acc=session.acc[:6], t_acc=session.t_acc[:6],
                         gyro=session.gyro[:6], t_gyro=session.t_gyro[:6])
    c = check(stored_calibration(truth), STORED, tiny)
    assert c.level == CANNOT_TELL and c.moments.count == 0
    assert "too few still moments (0" in c.reason
    import json

    json.dumps(c.to_dict(), allow_nan=False)  # --json: no NaN in the figures


def test_refreshed_from_20_moments_the_next_ones_read_within_3_mg():
    """The issue's figure, held out: refreshed from the first 20 moments of a jumping day
    (covering 0.3 g on both sides of every axis), the later moments' still-norm RMS under the
    refreshed calibration is within 3 mg (GGIR's best cohort: 3.0 mg), from 5 mg and more."""
    import dataclasses

    drift = Drift(acc_bias=np.array([0.006, -0.008, 0.005]),
                  acc_scale=np.array([-0.002, 0.003, 0.0]))
    for seed in range(3):
        session, truth = make_everyday("jumps", minutes=15, seed=40 + seed, drift=drift)
        cal = stored_calibration(truth)
        m = check(cal, STORED, session).moments
        assert m.count >= 30
        cut = m.times[19, 1] + 0.5  # after the 20th moment
        first = session.t_acc < cut
        part = dataclasses.replace(session, acc=session.acc[first], t_acc=session.t_acc[first],
                                   gyro=session.gyro[first], t_gyro=session.t_gyro[first])
        fresh = refresh(cal, STORED, part)
        assert fresh.check.moments.count == 20 and fresh.check.acc_fit.covered.all()
        later = m.raw_mean[20:]
        from imucal.inuse.estimate import norm_errors

        stored_mg = np.sqrt(np.mean(norm_errors(cal.segments[0].acc, later, 1.0) ** 2)) * 1e3
        fresh_mg = np.sqrt(np.mean(norm_errors(fresh.acc, later, 1.0) ** 2)) * 1e3
        assert stored_mg > 5.0 and fresh_mg < 3.0, (stored_mg, fresh_mg)  # measured: 6.0-7.9
        # mg stored, 0.18-0.23 mg refreshed


def test_a_calibration_of_several_segments_is_checked_and_refreshed_by_its_last():
    from imucal.io.inuse_file import refreshed_dict

    session, truth = make_everyday("walk", minutes=10, seed=5,
                                   drift=Drift(gyro_bias=GYRO_DRIFT))
    old = SensorModel(T=np.eye(3), K=np.ones(3), b=np.full(3, 0.5))  # far off: not used
    cal = Calibration(segments=(SegmentModels(0.0, 10.0, old, old),
                                SegmentModels(20.0, 30.0, truth.stored_acc, truth.stored_gyro)),
                      acc_unit_raw="g", acc_unit="g", g=1.0, gyro_unit_raw="rad/s")
    c = check(cal, STORED, session)
    assert c.segment == 2 and any("the last" in n for n in c.notes)
    assert c.parts[0].level == HOLDS and c.parts[1].level == DRIFTED
    from imucal.io.calibration_file import calibration_to_dict

    data = calibration_to_dict(cal)
    r = refresh(cal, STORED, session)
    new = refreshed_dict(data, r, calibration="c.json", calibration_sha256="0" * 64,
                         recording="r.mat", recording_sha256="1" * 64)
    assert len(new["segments"]) == 1 and new["refresh"]["segment"] == "the last of 2"
    seg = new["segments"][0]
    assert seg["t_start"] == 20.0 and seg["gyroscope"]["T"] == data["segments"][1]["gyroscope"]["T"]
    np.testing.assert_allclose(seg["gyroscope"]["b"], truth.gyro.b, atol=np.radians(0.05))
    assert data["segments"][1]["gyroscope"]["b"] == truth.stored_gyro.b.tolist()  # not touched


def test_a_drift_no_bias_or_scale_explains_is_said_so():
    """A misalignment that moved (a knock that tilted the accelerometer's z axis by 1 deg
    towards x) reads as drifted; refreshing biases and scales would not predict held-out
    moments better, so none is named or refreshed and the check says to recalibrate."""
    from imucal.models import acc_T

    session, truth = make_everyday("jumps", minutes=10, seed=8)
    tilted = SensorModel(T=acc_T(np.r_[0.0, np.radians(1.0), 0.0, 1, 1, 1, 0, 0, 0])
                         @ truth.stored_acc.T, K=truth.stored_acc.K, b=truth.stored_acc.b)
    raw = tilted.invert(truth.acc.apply(session.acc))  # the same motion, the new sensor
    import dataclasses

    tilted_session = dataclasses.replace(session, acc=raw)
    c = check(stored_calibration(truth), STORED, tilted_session)
    acc = c.parts[0]
    assert acc.level == DRIFTED and acc.value > 3.0, acc.reason  # measured 4.3 mg
    assert c.acc_fit.covered.all() and c.acc_fit.choice == "none"
    held = c.acc_fit.held_out_mg  # measured: none 4.3, bias 4.8, bias and scale 4.9 mg
    assert held["none"] < min(held["bias"], held["bias and scale"])
    assert acc.changes == () and acc.reason.endswith("(held out): recalibrate")
    r = refresh(stored_calibration(truth), STORED, tilted_session)
    assert not any(e.sensor == "accelerometer" for e in r.changed)
    assert any(k.startswith("accelerometer biases and scales: held-out") for k in r.kept)
