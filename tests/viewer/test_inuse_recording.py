"""Issue 26, item 5: the recording of ``imucal check`` and ``imucal refresh``, read back from the
.rrd (headless): the still moments on the recording's timeline, the still-norm error and the
gyroscope's rate at rest per axis moment by moment and as they built up, against the stored
value and the band the check holds them to (a drifted bias's rows beyond it, a bias that holds
inside it), and what refresh changed; ``--rrd`` on both commands, all outputs or none."""

from __future__ import annotations

import json

import numpy as np
import pytest

from imucal.cli.main import main
from imucal.inuse.check import HOLDS, Z95, Stored, check
from imucal.inuse.everyday import Drift, make_everyday
from imucal.inuse.refresh import refresh
from imucal.inuse.trace import running_norm, running_rate
from imucal.stages.apply import Calibration, SegmentModels
from viewer import paths as P
from viewer import readback as rb
from viewer.inuse import check_note, save_check_recording

STORED = Stored(static_norm_mg=0.3, acc_noise_density=0.003 / 10.0)
GYRO_DRIFT_DEG_S = np.array([0.3, -0.25, 0.2])
ACC_DRIFT_G = np.array([0.006, -0.004, 0.005])


def _calibration(truth) -> Calibration:
    return Calibration(segments=(SegmentModels(0.0, 0.0, truth.stored_acc, truth.stored_gyro),),
                       acc_unit_raw="g", acc_unit="g", g=1.0, gyro_unit_raw="rad/s")


@pytest.fixture(scope="module")
def drifted(tmp_path_factory):
    """Ten minutes of walking with the gyroscope's bias and the accelerometer's moved."""
    session, truth = make_everyday("walk", minutes=10, seed=1, drift=Drift(
        gyro_bias=np.radians(GYRO_DRIFT_DEG_S), acc_bias=ACC_DRIFT_G))
    cal = _calibration(truth)
    d = tmp_path_factory.mktemp("inuse")
    c = check(cal, STORED, session)
    save_check_recording(c, cal, session, d / "check.rrd")
    r = refresh(cal, STORED, session)
    save_check_recording(r.check, cal, session, d / "refresh.rrd", refresh=r)
    return session, truth, c, r, d


def test_still_moments_on_the_timeline(drifted):
    _, _, c, _, d = drifted
    t, states = rb.column(d / "check.rrd", P.INUSE_MOMENTS, "StateChange:state")
    np.testing.assert_allclose(t, c.moments.times.ravel(), atol=1e-9)
    assert [s if isinstance(s, str) else s[0] for s in states] == ["still", ""] * c.moments.count
    assert c.moments.count >= 8
    ta, a = rb.scalars(d / "check.rrd", P.INUSE_ACC_NORM)
    assert len(ta) <= 20_000 and ta[0] == 0.0
    inside = (ta >= t[0]) & (ta <= t[1])  # the first moment: |a| within a few % of |g|
    assert np.all(np.abs(a[inside] - 1.0) < 0.05) and a.max() > 1.3  # walking's steps


def test_still_norm_error_per_moment_and_as_it_built_up(drifted):
    _, _, c, _, d = drifted
    rrd = d / "check.rrd"
    acc = c.parts[0]
    t, e = rb.scalars(rrd, P.INUSE_NORM_MOMENT)
    np.testing.assert_allclose(t, c.moments.times.mean(axis=1), atol=1e-9)
    np.testing.assert_allclose(e, c.acc_fit.errors_before * 1e3, rtol=1e-12)
    tr, rms = rb.scalars(rrd, P.INUSE_NORM_RMS)
    np.testing.assert_allclose(tr, c.moments.times[1:, 1], atol=1e-9)
    # the last row is the check's own figure and its 95 % interval
    np.testing.assert_allclose(rms[-1], [acc.value, acc.low, acc.high], rtol=1e-9)
    k = np.arange(2, len(e) + 1)
    np.testing.assert_allclose(rms[:, 0], np.sqrt(np.cumsum(e**2)[1:] / k), rtol=1e-12)
    assert np.all(rms[:, 1] < rms[:, 0]) and np.all(rms[:, 2] > rms[:, 0])
    _, limit = rb.scalars(rrd, P.INUSE_NORM_LIMIT)
    _, expected = rb.scalars(rrd, P.INUSE_NORM_EXPECTED)
    np.testing.assert_array_equal(limit, [acc.limit] * 2)
    np.testing.assert_array_equal(expected, [acc.expected] * 2)
    # 6, -4, 5 mg of bias drift: the band's low edge ends above the limit (drifted)
    assert rms[-1, 1] > acc.limit and acc.level == "drifted"
    assert not rb.scalars(rrd, P.INUSE_NORM_REFRESHED)[0].size  # a check refreshes nothing


def test_a_drifted_gyroscope_bias_crosses_the_band(drifted):
    _, truth, c, _, d = drifted
    rrd = d / "check.rrd"
    limit = c.parts[1].limit
    expected = truth.stored_gyro.matrix @ np.radians(GYRO_DRIFT_DEG_S)  # what the stored
    for i, a in enumerate("xyz"):                                      # model leaves, rad/s
        _, band = rb.scalars(rrd, P.inuse_gyro(a, "band_deg_s"))
        np.testing.assert_array_equal(band, [[-limit, 0.0, limit]] * 2)
        t, m = rb.scalars(rrd, P.inuse_gyro(a, "moment_deg_s"))
        np.testing.assert_allclose(m[:, 0], np.degrees(c.moments.rate[:, i]), rtol=1e-12)
        np.testing.assert_allclose(m[:, 2] - m[:, 0], Z95 * np.degrees(c.moments.rate_se[:, i]))
        t, pooled = rb.scalars(rrd, P.inuse_gyro(a, "pooled_deg_s"))
        np.testing.assert_allclose(t, c.moments.times[:, 1], atol=1e-9)
        # the last row is the check's pooled rate and interval
        np.testing.assert_allclose(pooled[-1, 0], np.degrees(c.gyro.rate[i]), rtol=1e-9)
        np.testing.assert_allclose(pooled[-1, 2] - pooled[-1, 0],
                                   Z95 * np.degrees(c.gyro.rate_se[i]), rtol=1e-9)
        # every moment and the pooled band lie beyond the band on the drift's side
        side = np.sign(expected[i])
        assert np.all(side * m[:, 0] > limit), m[:, 0]
        assert np.all(side * pooled[:, 1 if side > 0 else 2] > limit)
        assert pooled[-1, 0] == pytest.approx(np.degrees(expected[i]), abs=0.02)


def test_a_bias_that_holds_stays_inside_the_band(tmp_path):
    session, truth = make_everyday("walk", minutes=10, seed=4)
    cal = _calibration(truth)
    c = check(cal, STORED, session)
    assert c.level == HOLDS
    save_check_recording(c, cal, session, tmp_path / "holds.rrd")
    for a in "xyz":
        _, pooled = rb.scalars(tmp_path / "holds.rrd", P.inuse_gyro(a, "pooled_deg_s"))
        assert np.all(np.abs(pooled[2:, 0]) < c.parts[1].limit)
        assert pooled[-1, 1] < 0.0 < pooled[-1, 2]  # the stored bias inside the interval
    _, rms = rb.scalars(tmp_path / "holds.rrd", P.INUSE_NORM_RMS)
    assert rms[-1, 1] < c.parts[0].limit


def test_running_figures_end_at_the_checks(drifted):
    _, _, c, _, _ = drifted
    run = running_rate(c)
    np.testing.assert_allclose(run.value[-1], np.degrees(c.gyro.rate), rtol=1e-12)
    np.testing.assert_allclose(run.high[-1] - run.value[-1], Z95 * np.degrees(c.gyro.rate_se),
                               rtol=1e-9)
    norm = running_norm(c, 1.0)
    acc = c.parts[0]
    assert (norm.value[-1], norm.low[-1], norm.high[-1]) == pytest.approx(
        (acc.value, acc.low, acc.high), rel=1e-12)


def test_what_refresh_changed(drifted):
    _, truth, _, r, d = drifted
    rrd = d / "refresh.rrd"
    v = rb.values(rrd, P.INUSE_REFRESH)
    assert v["parameter"] == [e.parameter for e in r.changed]
    np.testing.assert_array_equal(v["stored"], [e.stored for e in r.changed])
    np.testing.assert_array_equal(v["value"], [e.value for e in r.changed])
    np.testing.assert_array_equal(v["std_error"], [e.std_error for e in r.changed])
    gyro = [e for e in r.changed if e.sensor == "gyroscope"]
    np.testing.assert_allclose([e.value for e in gyro], truth.gyro.b, atol=np.radians(0.05))
    plot = rb.values(rrd, P.series(P.refresh_plot("gyroscope_bias"), "change"))
    xy = np.reshape(np.asarray(plot["Points2D:positions"], float), (-1, 2))
    np.testing.assert_allclose(xy[:, 1], np.degrees([e.change for e in gyro]), rtol=1e-6)
    np.testing.assert_allclose(xy[:, 1], GYRO_DRIFT_DEG_S, atol=0.05)  # the drift put in
    np.testing.assert_allclose(plot["std_error"], [e.std_error for e in gyro])
    acc = rb.values(rrd, P.series(P.refresh_plot("accelerometer_bias"), "change"))
    acc_xy = np.reshape(np.asarray(acc["Points2D:positions"], float), (-1, 2))
    np.testing.assert_allclose(acc_xy[:, 1], ACC_DRIFT_G * 1e3, atol=1.5)  # mg
    _, after = rb.scalars(rrd, P.INUSE_NORM_REFRESHED)
    np.testing.assert_allclose(after, r.check.acc_fit.errors_after * 1e3, rtol=1e-12)
    assert np.sqrt(np.mean(after**2)) < 0.5 < r.norm_before_mg
    note = rb.values(rrd, P.INUSE_NOTE)["TextDocument:text"]
    assert note == check_note(r.check, r) and "| gyroscope b_x |" in note
    assert rb.blueprint_containers(rrd) == ["Check", "Refresh"]
    assert rb.blueprint_containers(d / "check.rrd") == ["Check"]
    assert not [e for e in rb.entities(d / "check.rrd") if e.startswith("refresh")]


# --- the commands ------------------------------------------------------------------------------


def _run(capsys, *args) -> tuple[int, str]:
    rc = main([str(a) for a in args])
    out = capsys.readouterr()
    assert "Traceback" not in out.err
    return rc, out.out + out.err


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    d = tmp_path_factory.mktemp("walk")
    assert main(["synth", str(d / "w.mat"), "--activity", "walk", "--seed", "7",
                 "--drift-gyro-bias", "0.4,0,0"]) == 0
    return d


def test_check_and_refresh_write_the_recording(walk, capsys, tmp_path):
    cal, rec = walk / "w.mat.calib.json", walk / "w.mat"
    rc, out = _run(capsys, "check", cal, rec, "--rrd", tmp_path / "c.rrd")
    assert rc == 1 and f"wrote {tmp_path / 'c.rrd'}" in out
    _, pooled = rb.scalars(tmp_path / "c.rrd", P.inuse_gyro("x", "pooled_deg_s"))
    assert pooled[-1, 0] == pytest.approx(0.4, abs=0.03)
    rc, out = _run(capsys, "refresh", cal, rec, "--out", tmp_path / "new.json",
                   "--rrd", tmp_path / "r.rrd")
    assert rc == 0 and "wrote" in out
    new = json.loads((tmp_path / "new.json").read_text())
    v = rb.values(tmp_path / "r.rrd", P.INUSE_REFRESH)
    changed = {c["parameter"]: c["value"] for c in new["refresh"]["changed"]
               if c["sensor"] == "gyroscope"}
    got = {p: x for p, s, x in zip(v["parameter"], v["sensor"], v["value"]) if s == "gyroscope"}
    assert got == changed and len(got) == 3


def test_refresh_writes_both_or_neither(walk, capsys, tmp_path):
    cal, rec = walk / "w.mat.calib.json", walk / "w.mat"
    # a recording that cannot go where asked: nothing is written, not even NEW.json
    rc, out = _run(capsys, "refresh", cal, rec, "--out", tmp_path / "new.json",
                   "--rrd", tmp_path / "missing" / "r.rrd")
    assert rc == 1 and "missing" in out
    assert not (tmp_path / "new.json").exists()
    # a recording that determines nothing (the walk between two rests): exit 2, neither
    # file; check's recording of it says why, with no moment
    from imucal.inuse.everyday import make_everyday
    from imucal.io.export import write_session_mat

    session, truth = make_everyday("walk", minutes=1.5, seed=7)
    a, b = truth.still[0, 1] + 0.5, truth.still[1, 0] - 0.5
    keep = (session.t_acc > a) & (session.t_acc < b)
    moving = type(session)(acc=session.acc[keep], t_acc=session.t_acc[keep] - a,
                           gyro=session.gyro[keep], t_gyro=session.t_gyro[keep] - a)
    write_session_mat(tmp_path / "m.mat", moving)
    rc, _ = _run(capsys, "refresh", cal, tmp_path / "m.mat", "--out", tmp_path / "n2.json",
                 "--rrd", tmp_path / "r2.rrd")
    assert rc == 2
    assert not (tmp_path / "n2.json").exists() and not (tmp_path / "r2.rrd").exists()
    rc, _ = _run(capsys, "check", cal, tmp_path / "m.mat", "--rrd", tmp_path / "c2.rrd")
    assert rc == 2
    v = rb.values(tmp_path / "c2.rrd", P.INUSE_CHECK)
    assert v["verdict"] == "cannot tell" and v["moments"] == 0
    assert not rb.scalars(tmp_path / "c2.rrd", P.INUSE_NORM_MOMENT)[0].size
    (tmp_path / "c2.rrd").unlink()
    # an output given twice is refused before any work
    rc, out = _run(capsys, "check", cal, rec, "--rrd", cal)
    assert rc == 1 and not list(tmp_path.glob("*.rrd"))
