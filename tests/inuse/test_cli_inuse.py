"""``imucal synth --activity``, ``imucal check`` and ``imucal refresh`` end to end, in process:
what they print, write and exit with (0 holds, 1 drifted, 2 cannot tell)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from cli_run import run

from imucal.cli.main import main


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    """Ten minutes of walking with the gyroscope's bias moved by 0.4 deg/s about x and the
    accelerometer's by 8 mg along z, and the calibration from before (synth writes it)."""
    d = tmp_path_factory.mktemp("walk")
    rc = main(["synth", str(d / "walk.mat"), "--activity", "walk", "--seed", "7",
               "--drift-gyro-bias", "0.4,0,0", "--drift-acc-bias", "0,0,8"])
    assert rc == 0
    return d


def test_check_says_drifted_and_which_and_exits_1(walk, capsys):
    rc, out, _ = run(capsys, "check", walk / "walk.mat.calib.json", walk / "walk.mat")
    assert rc == 1
    assert out.startswith("verdict         drifted: ")
    assert "b_x by +0.0069" in out  # 0.4 deg/s = 0.00698 rad/s
    assert "accelerometer   drifted" in out and "b_z by +0.008" in out
    rc, out, _ = run(capsys, "check", walk / "walk.mat.calib.json", walk / "walk.mat", "--json")
    data = json.loads(out)
    assert rc == 1 and data["verdict"] == "drifted" and data["exit_code"] == 1
    gyro = {p["sensor"]: p for p in data["parts"]}["gyroscope"]
    lo, hi = gyro["per_axis"]["x"]["ci95"]
    assert lo < 0.4 < hi and lo > 0.3
    assert data["still_moments"]["count"] >= 8
    assert data["still_moments"]["detector"]["window"] == 51  # 0.5 s at 100 Hz


def test_refresh_writes_only_what_changed_and_the_refreshed_one_holds(walk, capsys, tmp_path):
    new = tmp_path / "new.json"
    rc, out, _ = run(capsys, "refresh", walk / "walk.mat.calib.json", walk / "walk.mat",
                     "--out", new)
    assert rc == 0 and f"wrote {new}" in out
    old = json.loads((walk / "walk.mat.calib.json").read_text())
    got = json.loads(new.read_text())
    truth = json.loads((walk / "walk.mat.truth.json").read_text())
    seg0, seg1 = old["segments"][0], got["segments"][0]
    # unchanged parameters exactly as stored: the misalignments, the gyroscope's scales
    assert seg1["accelerometer"]["T"] == seg0["accelerometer"]["T"]
    assert seg1["gyroscope"]["T"] == seg0["gyroscope"]["T"]
    assert seg1["gyroscope"]["K"] == seg0["gyroscope"]["K"]
    assert got["units"] == old["units"] and got["noise"] == old["noise"]
    np.testing.assert_allclose(seg1["gyroscope"]["b"], truth["gyroscope"]["b"],
                               atol=np.radians(0.05))
    np.testing.assert_allclose(seg1["accelerometer"]["b"], truth["accelerometer"]["b"],
                               atol=1e-3)
    prov = got["refresh"]
    assert prov["recording"]["file"].endswith("walk.mat") and len(prov["recording"]["sha256"]) == 64
    changed = {(c["sensor"], c["parameter"]): c for c in prov["changed"]}
    assert abs(changed[("gyroscope", "b_x")]["change"] - np.radians(0.4)) < np.radians(0.05)
    assert changed[("gyroscope", "b_x")]["std_error"] > 0
    assert any("misalignments" in k for k in prov["kept"])
    rc, out, _ = run(capsys, "check", new, walk / "walk.mat")
    assert rc == 0 and out.startswith("verdict         holds: ")


def test_a_short_recording_cannot_tell_and_refresh_keeps_the_accelerometer(capsys, tmp_path):
    rc = main(["synth", str(tmp_path / "s.mat"), "--activity", "walk", "--minutes", "0.6"])
    assert rc == 0
    capsys.readouterr()
    rc, out, _ = run(capsys, "check", tmp_path / "s.mat.calib.json", tmp_path / "s.mat")
    assert rc == 2 and out.startswith("verdict         cannot tell: ")
    assert "too few still moments (2 of 6)" in out
    # two rests: enough for the gyroscope's bias (10 s), not for the accelerometer
    rc, out, _ = run(capsys, "refresh", tmp_path / "s.mat.calib.json", tmp_path / "s.mat",
                     "--out", tmp_path / "n.json")
    assert rc == 0 and "changed         gyroscope b_x" in out
    assert "changed         accelerometer" not in out
    assert "kept            accelerometer biases and scales: 2 still moments, 6 needed" in out
    old = json.loads((tmp_path / "s.mat.calib.json").read_text())["segments"][0]
    new = json.loads((tmp_path / "n.json").read_text())["segments"][0]
    assert new["accelerometer"] == old["accelerometer"]


def test_no_still_moment_determines_nothing_and_writes_nothing(capsys, tmp_path):
    from imucal.inuse.everyday import make_everyday
    from imucal.io.export import write_session_mat

    session, truth = make_everyday("walk", minutes=1.5, seed=0)
    a, b = truth.still[0, 1] + 0.5, truth.still[1, 0] - 0.5  # the walk between two rests
    keep = (session.t_acc > a) & (session.t_acc < b)
    moving = type(session)(acc=session.acc[keep], t_acc=session.t_acc[keep] - a,
                           gyro=session.gyro[keep], t_gyro=session.t_gyro[keep] - a)
    write_session_mat(tmp_path / "m.mat", moving)
    rc = main(["synth", str(tmp_path / "c.mat"), "--activity", "walk", "--minutes", "1.5"])
    capsys.readouterr()
    assert rc == 0  # c.mat.calib.json: the same sensor (seed 0)
    rc, out, _ = run(capsys, "check", tmp_path / "c.mat.calib.json", tmp_path / "m.mat")
    assert rc == 2 and "still moments   0," in out
    rc, out, _ = run(capsys, "refresh", tmp_path / "c.mat.calib.json", tmp_path / "m.mat",
                     "--out", tmp_path / "n.json")
    assert rc == 2 and "nothing written" in out and not (tmp_path / "n.json").exists()


def test_bad_inputs_are_one_line(capsys, tmp_path, walk):
    bad = tmp_path / "bad.json"
    bad.write_text('{"format": "imucal-calibration", "format_version": 2, "units": {}}')
    rc, _, err = run(capsys, "check", bad, walk / "walk.mat")
    assert rc == 1 and err.startswith("imucal: error: ") and len(err.strip().splitlines()) == 1
    rc, _, err = run(capsys, "synth", tmp_path / "x.mat", "--activity", "swim")
    assert rc == 2
    rc, _, err = run(capsys, "synth", tmp_path / "x.mat", "--activity", "walk",
                     "--drift-gyro-bias", "1,2")
    assert rc == 2 and "X,Y,Z" in err


def test_the_limits_are_the_users_to_set(walk, capsys):
    """A bias moved by 0.4 deg/s is drifted at the default 0.1 deg/s and holds at 1 deg/s;
    the accelerometer's 8 mg too at a 20 mg limit: the verdict follows the limits given."""
    rc, out, _ = run(capsys, "check", walk / "walk.mat.calib.json", walk / "walk.mat", "--json",
                     "--gyro-limit", "1", "--acc-limit", "20")
    data = json.loads(out)
    assert rc == 0 and data["verdict"] == "holds"
    limits = {p["sensor"]: p["limit"] for p in data["parts"]}
    assert limits == {"accelerometer": 20.0, "gyroscope": 1.0}
    rc, _, _ = run(capsys, "check", walk / "walk.mat.calib.json", walk / "walk.mat",
                   "--gyro-limit", "1")
    assert rc == 1  # the accelerometer's 8 mg is still beyond 2 mg
    rc, _, err = run(capsys, "check", walk / "walk.mat.calib.json", walk / "walk.mat",
                     "--gyro-limit", "-1")
    assert rc == 2 and "positive" in err


def test_moments_only_without_a_calibration(walk, capsys, tmp_path):
    """``check --moments-only RECORDING``: the still moments of the walk as recorded (its
    rests, in as many orientations), the noise learned from it, and what they would suffice
    for; exit 0 when check could judge both sensors, 2 when not (one rest of a short walk)."""
    truth = json.loads((walk / "walk.mat.truth.json").read_text())
    rc, out, _ = run(capsys, "check", "--moments-only", walk / "walk.mat", "--json")
    data = json.loads(out)
    assert rc == 0 and data["exit_code"] == 0
    moments = data["still_moments"]
    assert moments["count"] >= 10 and moments["orientations"] >= 6
    still = np.array(truth["still_intervals"])
    for m in moments["moments"]:  # every moment inside a rest of the truth
        a, b = m["t"]
        assert ((still[:, 0] <= a + 0.35) & (still[:, 1] >= b - 0.35)).any()
    assert moments["detector"]["reference_from"].startswith("the quietest 1 %")
    noise = data["noise_learned"]  # the synthetic sensor's 3 mg per sample
    assert 2.0 < noise["mg_per_sample"] < 3.5 and noise["plausible_at_rest"]
    assert data["suffices"] == {"check_accelerometer": True, "check_gyroscope": True,
                                "refresh_gyroscope_bias": True,
                                "refresh_accelerometer_axes": ["x", "y", "z"]}
    rc, out, _ = run(capsys, "check", "--moments-only", walk / "walk.mat")
    assert rc == 0 and f"still moments   {moments['count']}, " in out
    assert "check accel.    yes" in out and "refresh accel.  bias and scale of x, y, z" in out
    rc, out, _ = run(capsys, "check", "--moments-only", walk / "walk.mat", "--acc-only")
    assert rc == 0 and "check gyro" not in out and "rate at rest" not in out
    rc = main(["synth", str(tmp_path / "s.mat"), "--activity", "walk", "--minutes", "0.6"])
    capsys.readouterr()
    rc, out, _ = run(capsys, "check", "--moments-only", tmp_path / "s.mat")
    assert rc == 2 and "check accel.    no: 2 moment(s)" in out and "check gyro      yes" in out


def test_moments_only_refusals(walk, capsys, tmp_path):
    rc, _, err = run(capsys, "check", "--moments-only", walk / "walk.mat",
                     walk / "walk.mat.calib.json")
    assert rc == 2 and "the recording alone" in err
    rc, _, err = run(capsys, "check", "--moments-only", walk / "walk.mat", "--gyro-limit", "1")
    assert rc == 2 and "judge a calibration" in err
    rc, _, err = run(capsys, "check", walk / "walk.mat.calib.json")
    assert rc == 2 and "--moments-only RECORDING" in err
    counts = tmp_path / "counts.csv"  # raw counts: no |g| without a calibration
    counts.write_text("t,ax,ay,az\n" + "".join(f"{i / 100},{100 + i % 3},{-20 + i % 2},"
                                               f"{16000 + i % 5}\n" for i in range(600)))
    rc, _, err = run(capsys, "check", "--moments-only", counts, "--acc-unit", "counts",
                     "--acc-only")
    assert rc == 1 and err.startswith("imucal: error: counts.csv: accelerometer unit: ")
    assert len(err.strip().splitlines()) == 1
