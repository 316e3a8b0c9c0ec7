"""A sensor driven past its range reads flat at its limit: such stretches must neither pass as
still poses (accelerometer) nor as measured rotations (gyroscope), and the user is told."""

import dataclasses

import numpy as np

import imucal
from imucal.models import gyro_theta
from imucal.stages.gyro import calibrate_gyroscope
from imucal.stages.saturation import saturated_mask
from imucal.synth import make_session


def test_saturated_mask_finds_flat_runs_only():
    rng = np.random.default_rng(0)
    x = rng.normal(0, 1, (2000, 3))
    assert not saturated_mask(x).any()  # noise touches its maximum once, not 5 times in a row
    x[100:130, 1] = x[:, 1].max() + 1.0  # clipped high on y for 30 samples
    x[500:504, 2] = x[:, 2].min() - 1.0  # 4 samples: too short to call clipping
    m = saturated_mask(x)
    assert np.flatnonzero(m).tolist() == list(range(100, 130))


def _clipped(session, limit):
    return dataclasses.replace(session, gyro=np.clip(session.gyro, -limit, limit))


def test_rotations_through_saturated_gyro_samples_are_left_out():
    session, truth = make_session(poses=40, seed=11)
    # A limit that only the fastest turns reach: a few transitions saturate.
    peak = np.abs(session.gyro).max(axis=0).min()
    limit = 0.8 * peak
    clipped = _clipped(session, limit)
    sat = saturated_mask(clipped.gyro)
    assert sat.any()

    result = imucal.calibrate(clipped, single_segment=True)
    g = result.segments[0].gyro
    n_out = int(g.excluded.sum())
    assert 1 <= n_out < len(g.excluded) // 2
    assert any(f"{n_out} of {len(g.excluded)} rotations" in w.message and "left out" in w.message
               for w in result.warnings), result.warnings
    # The left-out transitions are exactly those that contain a flat sample.
    t0, t1 = g.t_transition[:, 0], g.t_transition[:, 1]
    t_sat = clipped.t_gyro[sat]
    touched = np.array([np.any((t_sat >= a) & (t_sat <= b)) for a, b in zip(t0, t1)])
    np.testing.assert_array_equal(g.excluded, touched)

    # With them left out the gyroscope is recovered as from the unclipped session; fitted on
    # them anyway (the old behaviour) its scales come out wrong by many standard errors.
    seg = result.segments[0]
    err = np.abs(gyro_theta(g.model) - gyro_theta(truth.gyro)) / g.std
    assert err.max() < 4.0, err
    acc = seg.acc
    det = result.detection
    b0, b1 = seg.blocks
    naive = calibrate_gyroscope(clipped.gyro, clipped.t_gyro, result.block_times[b0:b1],
                                acc.model.apply(det.means[b0:b1]), clipped.gyro_unit)
    err_naive = np.abs(gyro_theta(naive.model) - gyro_theta(truth.gyro)) / g.std
    assert err_naive.max() > 3 * err.max(), (err_naive, err)
    # The quality figure leaves them out too; the recording still shows them.
    assert len(g.angle_after) == len(g.excluded)
    rms_kept = float(np.sqrt(np.mean(g.angle_after[~g.excluded] ** 2)))
    assert result.quality.gravity_angle_rms_deg.after == rms_kept


def test_saturated_still_blocks_are_excluded():
    session, _ = make_session(poses=30, seed=5)
    base = imucal.calibrate(session, single_segment=True)
    n0 = len(base.detection.blocks)
    # Clip z where the sensor lies z-up, so a still block reads flat at the limit.
    z = session.acc[:, 2]
    limit = np.quantile(z, 0.97)
    acc = session.acc.copy()
    acc[:, 2] = np.minimum(z, limit)
    clipped = dataclasses.replace(session, acc=acc)
    result = imucal.calibrate(clipped, single_segment=True)
    msg = [w for w in result.warnings if "saturated accelerometer" in w.message]
    assert msg, result.warnings
    n_ex = int(msg[0].message.split()[1])
    assert n_ex >= 1 and len(result.detection.blocks) == n0 - n_ex
    assert result.quality.static_norm_rms_mg.after < 2.0


def _two_pass_runs(x, min_run, chunk):
    """saturated_runs as it was: the column extremes first, then where each axis equals them
    (a mask of the whole column, its runs)."""
    x = np.asarray(x)
    found = [np.zeros((0, 2), np.int64)]
    for j in range(x.shape[1]):
        for ext in (x[:, j].max(), x[:, j].min()):
            m = np.concatenate([[False], x[:, j] == ext, [False]]).astype(np.int8)
            edges = np.flatnonzero(np.diff(m))
            runs = edges.reshape(-1, 2)
            found.append(runs[runs[:, 1] - runs[:, 0] >= min_run])
    runs = np.concatenate(found)
    mask = np.zeros(len(x) + 1, bool)
    for a, b in runs:
        mask[a:b] = True
    m = np.concatenate([[False], mask[:-1], [False]]).astype(np.int8)
    return np.flatnonzero(np.diff(m)).reshape(-1, 2)


def test_one_pass_runs_are_the_two_pass_runs():
    """Each chunk's own extremes kept while they equal the extreme so far: the same runs as
    the signal's extremes found first, whatever the chunking (clipped runs across chunk edges,
    an extreme that first appears late, integer codes with many ties, a NaN column)."""
    from imucal.stages.saturation import axis_saturated_runs, saturated_runs

    rng = np.random.default_rng(3)
    for trial in range(40):
        n = int(rng.integers(50, 5000))
        if trial % 3 == 0:
            x = rng.integers(-3, 4, (n, 3)).astype(float)  # few codes: ties everywhere
        else:
            x = rng.normal(0, 1, (n, 3))
        for _ in range(int(rng.integers(0, 4))):  # clipped stretches at a new extreme
            a = int(rng.integers(0, n - 1))
            b = min(n, a + int(rng.integers(1, 40)))
            j = int(rng.integers(0, 3))
            x[a:b, j] = (9.0 if rng.random() < 0.5 else -9.0)
        chunk = int(rng.integers(1, 700))
        runs = saturated_runs(x, 5, chunk)
        assert np.array_equal(runs, _two_pass_runs(x, 5, chunk)), trial
        per_axis = axis_saturated_runs(x, 5, chunk)
        for j in range(3):
            assert np.array_equal(per_axis[j], _two_pass_runs(x[:, j:j + 1], 5, chunk)), trial
    x = np.zeros((100, 2))
    x[50, 0] = np.nan  # numpy's extremes of column 0 are NaN: nothing equals them
    per_axis = axis_saturated_runs(x, 5, 16)
    assert len(per_axis[0]) == 0 and per_axis[1].tolist() == [[0, 100]]
