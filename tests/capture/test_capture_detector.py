"""The live still detector (imucal/capture/detector.py): holds where the synthetic session was
still, the same holds whatever the batch sizes, and the pose to hold next."""

import numpy as np

from imucal.capture.detector import StillDetector, centred
from imucal.synth import make_session


def _holds(session, sizes):
    det = StillDetector()
    i, k = 0, 0
    while i < len(session.t_acc):
        n = sizes[k % len(sizes)]
        st = det.feed(session.t_acc[i:i + n], session.acc[i:i + n])
        i, k = i + n, k + 1
    return det, st


def test_holds_match_the_still_intervals_and_batches_do_not_matter():
    session, truth = make_session(poses=12, seed=5, still=3.0)
    det, st = _holds(session, [37])
    starts = np.array([h.start for h in det.holds])
    ends = np.array([h.end for h in det.holds])
    # Every pose but the last (still in progress at the end) is a hold, inside its interval
    # give or take the window (0.25 s).
    assert len(det.holds) == 11
    np.testing.assert_allclose(starts, truth.pose_times[:11, 0], atol=0.35)
    np.testing.assert_allclose(ends, truth.pose_times[:11, 1], atol=0.35)
    assert st.state == "still" and st.hold_s > 2.0
    # The hold's mean is the gravity direction: the raw acceleration is ~1 g.
    norms = np.linalg.norm([h.mean for h in det.holds], axis=1)
    assert np.all(np.abs(norms - 1) < 0.1)
    other, _ = _holds(session, [3, 250, 11])
    assert [(h.start, h.end) for h in other.holds] == [(h.start, h.end) for h in det.holds]
    np.testing.assert_allclose([h.mean for h in other.holds], [h.mean for h in det.holds],
                               rtol=1e-12)
    assert det.orientations == other.orientations >= 9


def test_next_pose_names_an_uncovered_axis():
    session, _ = make_session(poses=3, seed=1)
    det, st = _holds(session, [100])
    suggested = st.next_pose
    assert suggested.endswith(" up") and st.coverage < 0.5
    # The suggestion points away from every pose held.
    axis = {"+x": [1, 0, 0], "-x": [-1, 0, 0], "+y": [0, 1, 0], "-y": [0, -1, 0],
            "+z": [0, 0, 1], "-z": [0, 0, -1]}
    v = np.sum([axis[w] for w in suggested[:-3].split(", ")], axis=0)
    v = v / np.linalg.norm(v)
    up = np.array([h.mean / np.linalg.norm(h.mean) for h in det.holds])
    assert np.max(up @ v) < np.cos(np.radians(30))


def test_raw_counts_count_their_poses_about_the_zero_offset():
    # 4096 counts per g about 32768: about the origin every pose points the same way.
    g, _ = make_session(poses=14, seed=2)
    counts, _ = make_session(poses=14, seed=2, acc_unit="counts")
    det_g, _ = _holds(g, [50])
    det_c, _ = _holds(counts, [50])
    assert det_c.orientations == det_g.orientations >= 11
    means = np.array([h.mean for h in det_c.holds])
    np.testing.assert_allclose(centred(means) + 32768, means, atol=0.1 * 4096)
    assert np.all(np.abs(np.linalg.norm(centred(means), axis=1) / 4096 - 1) < 0.1)
