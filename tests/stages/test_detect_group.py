"""Static detector (M1) and grouping into segments (method.md §1, §2)."""

import numpy as np
import pytest

import imucal
from imucal.errors import ImucalError
from imucal.numerics.windows import rolling_variance, runs_of_true
from imucal.settings import Settings
from imucal.stages.detect import INIT_MAX_F, detect_static, wander_ratio
from imucal.synth import make_session


def test_rolling_variance_matches_direct_windows():
    rng = np.random.default_rng(0)
    x = rng.normal(1000.0, 0.01, (500, 3))  # a large offset: cancellation would show here
    w = 11
    got = rolling_variance(x, w)
    h = w // 2
    for i in range(h, len(x) - h):
        np.testing.assert_allclose(got[i], np.var(x[i - h:i + h + 1], axis=0, ddof=1),
                                   rtol=1e-6)


def test_runs_of_true():
    m = np.array([1, 1, 0, 0, 1, 0, 1, 1, 1], bool)
    assert runs_of_true(m).tolist() == [[0, 2], [4, 5], [6, 9]]
    assert runs_of_true(np.zeros(4, bool)).shape == (0, 2)


def test_blocks_match_the_still_poses():
    session, truth = make_session(poses=25, seed=1)
    det = detect_static(session.acc, session.t_acc)
    assert len(det.blocks) == 25
    t = session.t_acc
    for (a, b), (s, e) in zip(det.blocks, truth.pose_times):
        # Inside its pose, and covering most of it (the centred window trims half a window).
        assert t[a] >= s - 1e-9 and t[b - 1] <= e + 1e-9
        assert (t[b - 1] - t[a]) > (e - s) - 1.2


def test_detector_statistic_is_m1():
    session, _ = make_session(poses=12, seed=2)
    det = detect_static(session.acc, session.t_acc, Settings(window=51).detect)
    var = rolling_variance(session.acc, 51)
    np.testing.assert_allclose(det.statistic(session.acc), (var**2).sum(axis=1))
    imu = detect_static(session.acc, session.t_acc, Settings(window=51, statistic="imu_tk").detect)
    np.testing.assert_allclose(imu.statistic(session.acc), np.sqrt((var**2).sum(axis=1)))


def test_no_initial_still_period_is_reported():
    session, _ = make_session(poses=12, seed=3)
    with pytest.raises(ImucalError, match="initial still"):
        detect_static(session.acc, session.t_acc, Settings(init=(1e6, 1e6 + 2)).detect)


def test_wander_ratio_tells_still_from_moving():
    rng = np.random.default_rng(0)
    still = rng.normal(0, 0.003, (250, 3)) + [0, 0, 1]
    assert wander_ratio(still) < 5
    tilted = still.copy()
    tilted[125:] += [0.02, 0, -0.0002]  # turned by about a degree half way through
    assert wander_ratio(tilted) > 3 * INIT_MAX_F
    flat = still.copy()
    flat[:, 1] = 0.0  # a constant axis (quantised) neither moves nor divides by zero
    assert wander_ratio(flat) == pytest.approx(wander_ratio(still[:, [0, 2]]))


@pytest.mark.parametrize("still_at_start", [0.0, 1.0, 2.0])
def test_moving_start_learns_the_noise_from_the_quiet_stretches(still_at_start):
    """Without a still start the threshold learned from 0.5-3 s would be motion's: blocks would
    swallow turns and the calibration be wrong by tens of mg (measured: 51 mg, 21 degrees).
    The quiet level of the whole recording is used instead, and the user is told."""
    session, truth = make_session(poses=30, seed=2, init_still=still_at_start)
    r = imucal.calibrate(session)
    assert r.detection.init is None
    assert "quiet level" in r.detection.tuning.reference
    assert any("moves during the initial still interval 0.5-3 s" in w.message
               and "quietest stretches" in w.message for w in r.warnings)
    assert r.quality.static_norm_rms_mg.after < 0.5
    assert r.quality.gravity_angle_rms_deg.after < 0.2
    assert len(r.detection.blocks) >= 29


@pytest.mark.parametrize("still_at_start", [0.0, 1.0, 2.0])
def test_moving_start_given_interval_slides_to_the_first_still_stretch(still_at_start):
    """An interval the user gives (--init) that moves: the first still stretch as long."""
    session, truth = make_session(poses=30, seed=2, init_still=still_at_start)
    r = imucal.calibrate(session, init=(0.5, 3.0))
    assert r.detection.init != (0.5, 3.0)
    assert r.detection.init[0] >= still_at_start  # after the first turn began
    assert any("moves during the initial still interval 0.5-3 s" in w.message
               for w in r.warnings)
    assert r.quality.static_norm_rms_mg.after < 0.5
    assert r.quality.gravity_angle_rms_deg.after < 0.2
    assert len(r.detection.blocks) >= 29


def test_still_start_is_used_as_it_is():
    session, _ = make_session(poses=12, seed=3)
    det = detect_static(session.acc, session.t_acc)
    assert det.init == (0.5, 3.0) and det.note is None


def test_never_still_is_an_error():
    rng = np.random.default_rng(4)
    t = np.arange(6000) / 100.0
    acc = np.cumsum(rng.normal(0, 0.01, (6000, 3)), axis=0) + [0, 0, 1]  # always drifting
    with pytest.raises(ImucalError, match="never still for 2.5 s"):
        detect_static(acc, t)


def test_too_few_blocks_says_how_many():
    session, _ = make_session(poses=5, seed=3)
    with pytest.raises(ImucalError, match="found 5 static blocks"):
        imucal.calibrate(session)


def test_steady_session_gives_one_segment():
    for seed in (11, 12, 13):
        session, _ = make_session(poses=40, seed=seed)
        r = imucal.calibrate(session)
        assert len(r.segments) == 1, r.grouping.tests


def test_change_of_parameters_gives_two_segments_split_near_the_change():
    for seed in (21, 22):
        session, truth = make_session(poses=40, seed=seed, change_at=0.5)
        r = imucal.calibrate(session)
        assert len(r.segments) == 2, r.grouping.tests
        first, second = r.segments
        # The split falls in the motion where the parameters changed.
        assert first.t_end <= truth.t_change <= second.t_start
        # Each segment recovers its own truth.
        np.testing.assert_allclose(first.acc.model.K, truth.acc.K, rtol=3e-3)
        np.testing.assert_allclose(second.acc.model.K, truth.acc2.K, rtol=3e-3)
        assert r.quality.static_norm_rms_mg.after < 0.5
        # Samples between the two segments use the mean of their parameters (method.md §2).
        t = session.t_acc
        gap = (t > first.t_end) & (t < second.t_start)
        mean_k = (first.acc.model.K + second.acc.model.K) / 2
        mean_b = (first.acc.model.b + second.acc.model.b) / 2
        mean_t = (first.acc.model.T + second.acc.model.T) / 2
        expect = (session.acc[gap] - mean_b) @ (mean_t * mean_k).T
        np.testing.assert_allclose(r.calibrated.acc[gap], expect)


def test_single_segment_mode():
    session, _ = make_session(poses=40, seed=21, change_at=0.5)
    r = imucal.calibrate(session, single_segment=True)
    assert len(r.segments) == 1
    assert "single segment" in r.grouping.mode


def test_fast_split_search_agrees_with_exhaustive():
    # best_split scores every boundary by a Gauss-Newton model and fits only the best few;
    # it must land where fitting both sides of every boundary does.
    from imucal.stages.group import _fit, best_split, block_mean_variance, block_weights

    for seed, change in ((31, 0.4), (32, 0.65), (33, None)):
        session, _ = make_session(poses=36, seed=seed, change_at=change)
        r = imucal.calibrate(session, single_segment=True)
        m = r.whole.nominal.to_nominal(r.detection.means)
        var = block_mean_variance(session.acc, r.detection.blocks) / r.whole.nominal.scale**2
        lam = r.whole.lam * len(m) / r.whole.n_points
        start = r.whole.theta_nominal
        w, _ = block_weights(m, var, start)
        js = np.arange(12, len(m) - 12 + 1)
        costs = {}
        for j in js:
            _, c_a, _ = _fit(m[:j], w[:j], start, lam, centre=start)
            _, c_b, _ = _fit(m[j:], w[j:], start, lam, centre=start)
            costs[int(j)] = c_a + c_b
        exhaustive = min(costs, key=lambda j: (costs[j], j))
        assert best_split(m, w, start, lam, js)[0] == exhaustive
