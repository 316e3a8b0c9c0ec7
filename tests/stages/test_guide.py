"""The guide to a recording (imucal.stages.guide, viewer.guide): on synthetic sessions whose
poses and turns are chosen, the poses reached, the directions missing, the holds near the
detector's minimum and the turns over the limits come out as made; the recording holds the
same numbers."""

from __future__ import annotations

import numpy as np
import pytest

import imucal
from imucal.cli.summary import summary_lines
from imucal.numerics import quaternion as quat
from imucal.report import report
from imucal.session import Session
from imucal.stages.accel_cv import COVERAGE_ANGLE_DEG, coverage
from imucal.stages.guide import ADVISED_HOLD_S, MIN_TILT_DEG
from imucal.stages.gyro_transitions import angle_between
from imucal.synth import Motion, random_acc_model, random_gyro_model
from viewer import paths as P
from viewer import readback as rb
from viewer.recording import save_recording

RATE = 100.0
UP = np.array([0.0, 0.0, 1.0])


def _pose(up: np.ndarray, yaw: float) -> np.ndarray:
    """Body-to-world quaternion with the body direction ``up`` pointing up (R up = e_z), then
    turned by ``yaw`` about the vertical."""
    up = up / np.linalg.norm(up)
    axis = np.cross(up, UP)
    s = np.linalg.norm(axis)
    tilt = (axis / s * np.arctan2(s, up @ UP) if s > 1e-9
            else np.array([np.pi, 0, 0]) * (up @ UP < 0))
    return quat.multiply(quat.from_rotvec(UP * yaw), quat.from_rotvec(tilt))


def _session(ups: np.ndarray, holds: np.ndarray, moves: np.ndarray, seed: int = 0,
             gyro_counts: float | None = None) -> tuple[Session, Motion]:
    """A session holding each ``ups`` direction up for ``holds`` s, turning in ``moves`` s
    (minimum jerk, as imucal.synth); ``gyro_counts`` counts per rad/s makes the gyroscope
    16-bit integer codes around 32768 (full scale 32768 / gyro_counts rad/s)."""
    rng = np.random.default_rng(seed)
    q = np.array([_pose(u, y) for u, y in zip(ups, rng.uniform(-0.5, 0.5, len(ups)))])
    rv = quat.to_rotvec(quat.multiply(quat.conjugate(q[:-1]), q[1:]))
    angle = np.linalg.norm(rv, axis=1)
    starts = np.concatenate([[0.0], np.cumsum(holds[:-1] + moves)])
    motion = Motion(q=q, still=np.column_stack([starts, starts + holds]),
                    axis=rv / np.maximum(angle, 1e-12)[:, None], angle=angle)
    t = np.arange(int(motion.still[-1, 1] * RATE)) / RATE
    qa, w = motion.at(t)
    acc = random_acc_model(rng).invert(quat.rotate_inverse(qa, UP))
    gyro = random_gyro_model(rng).invert(w) + rng.normal(0, 0.003, w.shape)
    unit = "rad/s"
    if gyro_counts is not None:
        gyro, unit = np.clip(np.round(gyro * gyro_counts + 32768.0), 0, 65535), "counts"
    return Session(acc=acc + rng.normal(0, 0.003, acc.shape), t_acc=t, gyro=gyro, t_gyro=t,
                   acc_unit="g", gyro_unit=unit, source="guide-test"), motion


def _random_ups(n: int, rng: np.random.Generator, min_z: float = -1.0) -> np.ndarray:
    """``n`` directions with z >= min_z, each 25 degrees or more from the one before."""
    out: list[np.ndarray] = []
    while len(out) < n:
        v = rng.normal(size=3)
        v /= np.linalg.norm(v)
        if v[2] >= min_z and (not out or v @ out[-1] < np.cos(np.radians(25))):
            out.append(v)
    return np.array(out)


def _pose_of_blocks(result, motion: Motion) -> np.ndarray:
    mid = result.block_middles
    k = np.searchsorted(motion.still[:, 0], mid, side="right") - 1
    assert np.all(mid < motion.still[k, 1])  # every block inside one hold
    return k


@pytest.fixture(scope="module")
def whole_sphere():
    ups = _random_ups(20, np.random.default_rng(4))
    holds = np.full(20, 3.0)
    holds[0] = 5.0
    session, motion = _session(ups, holds, np.full(19, 1.5), seed=4)
    return imucal.calibrate(session), motion, ups


def test_poses_reached_match_the_truth(whole_sphere):
    result, motion, ups = whole_sphere
    g = result.guide
    k = _pose_of_blocks(result, motion)
    assert np.array_equal(k, np.arange(len(ups)))  # one block per hold
    err = angle_between(g.poses.gravity, ups[k])
    assert err.max() < 0.3, err  # deg: the calibrated direction is the pose's up axis
    missing, covered = coverage(ups)
    assert g.poses.coverage == pytest.approx(covered, abs=0.02)
    # 20 random poses leave 5.5 % of the sphere uncovered: weak (95 % needed), 2 poses to add
    assert g.poses.coverage < 0.95 and any("of the sphere" in t for t in g.weak)
    near = (missing @ g.poses.suggested.T).max(axis=1) >= np.cos(np.radians(COVERAGE_ANGLE_DEG))
    assert len(g.poses.suggested) == 2 and near.all()
    # Durations: each block's samples, inside its hold of 3 s (less the window's edges).
    assert g.holds.min_source == "chosen from the data"
    assert g.holds.min_s == pytest.approx(result.detection.min_len / RATE)
    blocks = result.detection.blocks
    np.testing.assert_allclose(g.holds.duration_s, (blocks[:, 1] - blocks[:, 0]) / RATE)
    hold = np.diff(motion.still, axis=1)[:, 0]
    assert np.all(g.holds.duration_s <= hold + 1e-9)
    assert np.all(g.holds.duration_s > hold - result.detection.window / RATE - 0.3)
    # Turns: the integrated rotation and the peak rate are the scripted ones.
    np.testing.assert_allclose(g.turns.angle_deg, np.degrees(motion.angle), atol=0.5)
    peak = 1.875 * motion.angle / np.diff(motion.still.ravel())[1::2]  # min jerk: 15/8 a/T
    np.testing.assert_allclose(g.turns.peak_rate, peak, rtol=0.03)
    assert not g.turns.fast.any() and not g.holds.near_min.any()


def test_a_missing_hemisphere_is_reported_with_what_to_record():
    rng = np.random.default_rng(7)
    ups = _random_ups(16, rng, min_z=0.35)  # never anything below the horizon
    holds = np.full(16, 3.0)
    holds[0] = 5.0
    session, motion = _session(ups, holds, np.full(15, 1.5), seed=7)
    result = imucal.calibrate(session)
    g = result.guide
    truth_missing, truth_cov = coverage(ups)
    assert g.poses.coverage == pytest.approx(truth_cov, abs=0.03)
    assert g.poses.coverage < 0.7
    # Every missing direction is far from every pose, and the lower pole is among them.
    assert np.all(g.poses.missing @ ups.T < np.cos(np.radians(COVERAGE_ANGLE_DEG)) + 0.02)
    assert np.max(g.poses.missing @ -UP) > 0.99
    assert len(g.poses.missing) >= 0.8 * len(truth_missing)
    # The suggested poses cover what is missing and point down, and the text says so.
    sug = g.poses.suggested
    assert 1 <= len(sug) <= 6 and np.all(sug[:, 2] < 0.3)
    near = (g.poses.missing @ sug.T).max(axis=1) >= np.cos(np.radians(COVERAGE_ANGLE_DEG))
    assert near.mean() > 0.9
    assert any("of the sphere" in w for w in g.weak)
    todo = " ".join(g.record_next)
    assert f"hold {len(sug)} more pose" in todo and "-z" in todo


def test_short_holds_are_flagged_against_the_minimum():
    rng = np.random.default_rng(11)
    ups = _random_ups(14, rng)
    holds = np.full(14, 4.0)
    short = np.array([3, 7, 10])
    holds[short] = 1.6  # a block of about 1.1 s with the 0.51 s window: under 1.5 x 1 s
    holds[0] = 5.0
    session, motion = _session(ups, holds, np.full(13, 1.5), seed=11)
    result = imucal.calibrate(session, window=51, min_len=100)
    h = result.guide.holds
    assert h.min_len == 100 and h.min_s == pytest.approx(1.0) and h.min_source == "given"
    k = _pose_of_blocks(result, motion)
    assert np.array_equal(k[h.near_min], short)
    # One minimum, said as a hold: a hold of 1.5 s makes a block of the 1 s minimum (the
    # 0.51 s window's edges); a block of 1.5 x the minimum comes from a hold of 2 s.
    assert h.count_s == pytest.approx(1.5) and h.near_s == pytest.approx(2.0)
    np.testing.assert_allclose(h.hold_s, h.duration_s + 0.5)
    assert np.all(h.hold_s[h.near_min] < 2.0) and np.all(h.hold_s[~h.near_min] >= 2.0)
    # The holds that barely counted are named by when they start (the poses made short).
    weak = [w for w in result.guide.weak if "barely counted" in w]
    assert len(weak) == 1 and "a hold counts from 1.5 s" in weak[0]
    starts = result.block_times[h.near_min, 0]
    np.testing.assert_allclose(starts, motion.still[short, 0], atol=0.5)
    assert f"3 barely counted, held under 2 s (at {starts[0]:.1f}, {starts[1]:.1f} and " \
           f"{starts[2]:.1f} s)" in weak[0]
    # One advice whatever the detector: 3 s (ADVISED_HOLD_S) clears this one's 2 s too.
    assert h.recommended_s == ADVISED_HOLD_S == 3.0
    assert "hold each pose still for 3 s or more" in result.guide.record_next
    assert all("1.5x" not in w and "minimum of" not in w for w in result.guide.weak)


def test_the_advice_is_one_hold_unless_the_detector_needs_longer():
    """The same advice on a file whatever window the detector takes; a window set by hand that
    needs longer holds raises it to what clears that detector's minimum."""
    rng = np.random.default_rng(12)
    ups = _random_ups(14, rng)
    holds = np.r_[5.0, np.full(13, 6.0)]
    session, motion = _session(ups, holds, np.full(13, 1.5), seed=12)
    chosen = imucal.calibrate(session).guide.holds
    narrow = imucal.calibrate(session, window=51, min_len=50).guide.holds
    assert chosen.recommended_s == narrow.recommended_s == ADVISED_HOLD_S
    wide = imucal.calibrate(session, window=301, min_len=300).guide.holds
    # 3 s of block and 3 s of window edges count; 1.5 x the block is 7.5 s of hold.
    assert wide.count_s == pytest.approx(6.0) and wide.recommended_s == pytest.approx(7.5)


def test_holds_too_short_are_named_by_time(shared_data):
    """imu2.log (MPU-9150, hand-held): the still stretches too short to make a block are each
    named by when it starts, outside every block, in the guide's sentence and calib.json."""
    from imucal.io.calibration_file import result_to_dict
    from imucal.stages.guide import at_times

    session = imucal.load_session(shared_data / "mikoff_mpu9150" / "imu2.log", rate=100.0)
    result = imucal.calibrate(session)
    h = result.guide.holds
    assert h.short_holds >= 5 and len(h.short_at_s) == h.short_holds
    bt = result.block_times
    inside = (h.short_at_s[:, None] >= bt[:, 0]) & (h.short_at_s[:, None] <= bt[:, 1])
    assert not inside.any()
    assert np.all((h.short_at_s >= session.t_acc[0]) & (h.short_at_s <= session.t_acc[-1]))
    line = [w for w in result.guide.weak if "did not count" in w]
    assert len(line) == 1 and f"{h.short_holds} shorter holds did not count " \
        f"({at_times(h.short_at_s)})" in line[0]
    assert at_times(h.short_at_s).endswith(f"s and {h.short_holds - 6} more")
    assert result_to_dict(result)["guide"]["short_holds_at_s"] == list(h.short_at_s)
    assert "hold each pose still for 3 s or more" in result.guide.record_next


def test_small_turns_are_one_idea_in_the_guide_and_the_warnings(tmp_path):
    """A turn tilting gravity 8 degrees is small for the guide, the gyroscope's warning and the
    viewer alike (one threshold, MIN_TILT_DEG), and it is named by its time."""
    rng = np.random.default_rng(5)
    ups = _random_ups(14, rng)
    side = np.cross(ups[8], [1.0, 0.0, 0.0])
    ups[9] = quat.rotate_inverse(quat.from_rotvec(side / np.linalg.norm(side)
                                                  * np.radians(8.0)), ups[8])
    ups[4] = quat.rotate_inverse(quat.from_rotvec(np.cross(ups[3], [0.0, 1.0, 0.0])
                                                  / np.linalg.norm(np.cross(ups[3], [0, 1, 0]))
                                                  * np.radians(12.0)), ups[3])
    session, motion = _session(ups, np.r_[5.0, np.full(13, 3.0)], np.full(13, 2.0), seed=5)
    result = imucal.calibrate(session)
    t = result.guide.turns
    assert np.flatnonzero(t.small).tolist() == [3, 8]  # 12 and 8 degrees: both under 15
    assert MIN_TILT_DEG == t.min_tilt_deg == 15.0
    small = [w for w in result.warnings if w.code == "gyro_rotations_small"]
    assert len(small) == 1 and small[0].message.startswith(
        "2 of 13 turns move gravity less than 15 deg")
    guide_line = [w for w in result.guide.weak if "move gravity" in w]
    assert guide_line == [f"2 of 13 turns move gravity less than 15 deg: they land in the same "
                          f"pose and tell the gyroscope little (at {t.times[3, 0]:.1f} and "
                          f"{t.times[8, 0]:.1f} s)"]
    path = tmp_path / "small.rrd"
    save_recording(result, path)
    _, line = rb.scalars(path, P.GUIDE_TURN_MIN_TILT)
    np.testing.assert_allclose(line, MIN_TILT_DEG)


def test_fast_and_small_turns_are_flagged_against_the_limits(tmp_path):
    rng = np.random.default_rng(5)
    ups = _random_ups(14, rng)
    # Turn 8 tilts by 8 degrees only (a pure yaw would not be seen by the accelerometer: the
    # detector joins its two holds into one block).
    side = np.cross(ups[8], [1.0, 0.0, 0.0])
    ups[9] = quat.rotate_inverse(quat.from_rotvec(side / np.linalg.norm(side)
                                                  * np.radians(8.0)), ups[8])
    holds = np.r_[5.0, np.full(13, 3.0)]
    _, motion = _session(ups, holds, np.full(13, 2.0), seed=5)  # the turns' angles
    fast = np.array([2, 5, 11])
    moves = np.maximum(1.875 * motion.angle / 1.5, 1.0)  # peaks of 1.5 rad/s at most
    moves[fast] = 1.875 * motion.angle[fast] / 4.6  # 4.6 rad/s: over the limit, not clipped
    # 16-bit codes at 6553.6 counts per rad/s: full scale 5 rad/s, limit 4 rad/s
    session, motion = _session(ups, holds, moves, seed=5, gyro_counts=6553.6)
    result = imucal.calibrate(session)
    assert len(result.block_times) == 14  # one block per hold: turn k leaves hold k
    t = result.guide.turns
    assert t.full_scale == pytest.approx(5.0, rel=0.02)
    assert t.rate_limit == pytest.approx(0.8 * t.full_scale)
    assert "full scale" in t.limit_source and "integer codes" in t.full_scale_source
    assert np.flatnonzero(t.fast).tolist() == fast.tolist()
    np.testing.assert_allclose(t.peak_rate[fast], 4.6, rtol=0.03)
    assert np.flatnonzero(t.small).tolist() == [8]
    assert t.tilt_deg[8] == pytest.approx(8.0, abs=0.3)
    todo = " ".join(result.guide.record_next)
    assert "turn more slowly" in todo and "tilt 15 deg" in todo
    # The recording shows the flagged turns again, at their times.
    path = tmp_path / "fast.rrd"
    save_recording(result, path)
    tf, rf = rb.scalars(path, P.GUIDE_TURN_FAST)
    np.testing.assert_allclose(tf, t.times[fast].mean(axis=1), atol=1e-6)
    np.testing.assert_allclose(rf, t.peak_rate[fast])


def test_rad_s_gyroscope_limit_comes_from_the_integration(whole_sphere):
    result, _, _ = whole_sphere
    t = result.guide.turns
    assert t.full_scale is None
    assert t.rate_limit == pytest.approx(np.radians(10.0) * RATE)
    assert "per sample" in t.limit_source


def test_summary_and_recording_hold_the_guide(whole_sphere, tmp_path):
    result, _, _ = whole_sphere
    g = result.guide
    rep = report(result)
    assert [line.label for line in rep.guide].count("record next") == len(g.record_next)
    text = "\n".join(summary_lines(rep))
    assert "guide to the recording:" in text and g.record_next[0] in text

    path = tmp_path / "guide.rrd"
    save_recording(result, path)
    t, d = rb.scalars(path, P.GUIDE_HOLD)
    np.testing.assert_allclose(t, result.block_middles, atol=1e-6)
    np.testing.assert_allclose(d, g.holds.hold_s)  # the holds, against the guide's numbers
    _, m = rb.scalars(path, P.GUIDE_HOLD_MIN)
    np.testing.assert_allclose(m, g.holds.count_s)
    _, a = rb.scalars(path, P.GUIDE_HOLD_WARN)
    np.testing.assert_allclose(a, g.holds.recommended_s)
    t, r = rb.scalars(path, P.GUIDE_TURN_RATE)
    np.testing.assert_allclose(t, g.turns.times.mean(axis=1), atol=1e-6)
    np.testing.assert_allclose(r, g.turns.peak_rate)
    _, tilt = rb.scalars(path, P.GUIDE_TURN_TILT)
    np.testing.assert_allclose(tilt, g.turns.tilt_deg)
    _, lim = rb.scalars(path, P.GUIDE_TURN_LIMIT)
    np.testing.assert_allclose(lim, g.turns.rate_limit)
    poses = rb.values(path, P.GUIDE_POSES)["Points3D:positions"]
    np.testing.assert_allclose(poses, g.poses.gravity, atol=1e-6)
    info = rb.values(path, P.GUIDE_INFO)
    assert info["rate_limit"] == pytest.approx(g.turns.rate_limit)
    assert info["min_s"] == pytest.approx(g.holds.min_s)
    assert list(np.atleast_1d(info["record_next"])) == list(g.record_next)
    views = [name for _, name in rb.blueprint_views(path)]
    assert any(name.startswith("Poses (axis up)") for name in views)


def test_calibration_file_holds_the_verdict(whole_sphere, tmp_path):
    import json

    from imucal.io.calibration_file import result_to_dict

    result, _, _ = whole_sphere
    d = json.loads(json.dumps(result_to_dict(result)))["guide"]
    g = result.guide
    assert d["record_next"] == list(g.record_next) and d["strong"] == list(g.strong)
    assert d["turn_rate_limit_rad_s"] == pytest.approx(g.turns.rate_limit)
    assert d["gyro_full_scale_rad_s"] is None and d["orientations"] == g.poses.orientations


def test_a_turn_too_fast_for_the_integration_is_one_idea_too():
    """The guide's rate limit (10 deg per sample, where the full scale is unknown) and the
    gyroscope fit's warning on fast rotations are the same threshold: one turn at about 13 deg
    per sample is flagged by both, the others by neither."""
    rng = np.random.default_rng(7)
    ups = _random_ups(14, rng)
    _, motion = _session(ups, np.r_[5.0, np.full(13, 3.0)], np.full(13, 2.0), seed=7)
    moves = np.maximum(1.875 * motion.angle / 1.5, 1.0)  # peaks of 1.5 rad/s at most
    moves[6] = 1.875 * motion.angle[6] / 23.0  # 23 rad/s at 100 Hz: 13 deg per sample
    session, _ = _session(ups, np.r_[5.0, np.full(13, 3.0)], moves, seed=7)
    result = imucal.calibrate(session)
    t = result.guide.turns
    assert t.rate_limit == pytest.approx(np.radians(10.0) * RATE)
    assert np.flatnonzero(t.fast).tolist() == [6]
    fast = [w for w in result.warnings if w.code == "gyro_rotations_fast"]
    assert len(fast) == 1 and "loses accuracy above about 10" in fast[0].message
    v = result.verdict  # and the verdict weighs it: the fit rests on the other turns
    assert v.level != "good" and "turns_too_fast" in {v.code, *(c.code for c in v.caveats)}
    calm, _ = _session(ups, np.r_[5.0, np.full(13, 3.0)], np.maximum(moves, 1.0), seed=7)
    calm_result = imucal.calibrate(calm)
    assert not calm_result.guide.turns.fast.any()
    assert not any(w.code == "gyro_rotations_fast" for w in calm_result.warnings)
