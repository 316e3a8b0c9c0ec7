"""Synthetic flights (imucal.inuse.flight, ``imucal synth --activity flight``): the still
moments are the rests before take-off and after landing and nothing else (the motors'
vibration and the touchdowns are not still), the gyroscope's drift is found and refreshed from
them, the accelerometer is left as stored (one orientation: no axis covered)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from imucal.cli.main import main
from imucal.inuse.check import DRIFTED, HOLDS, Stored, check
from imucal.inuse.everyday import Drift, make_everyday
from imucal.inuse.refresh import refresh
from imucal.stages.apply import Calibration, SegmentModels

STORED = Stored(static_norm_mg=0.3, acc_noise_density=0.0003)
DRIFT = Drift(gyro_bias=np.radians([0.3, -0.2, 0.15]), acc_bias=np.array([0.0, 0.0, 0.008]))


def calibration(truth) -> Calibration:
    return Calibration(segments=(SegmentModels(0.0, 0.0, truth.stored_acc, truth.stored_gyro),),
                       acc_unit_raw="g", acc_unit="g", g=1.0, gyro_unit_raw="rad/s")


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_moments_only_on_the_ground_with_the_motors_off(seed):
    session, truth = make_everyday("flight", minutes=10, seed=seed, drift=DRIFT)
    assert len(truth.still) >= 3 and len(truth.taps) >= 2
    r = refresh(calibration(truth), STORED, session)
    m = r.check.moments
    inside = [(truth.still[:, 0] <= a) & (truth.still[:, 1] >= b) for a, b in m.times]
    assert all(x.sum() == 1 for x in inside)  # zero false still moments
    assert m.count == len(truth.still)  # and every rest found (each 25-45 s)
    on = truth.disturbed
    assert not np.any((on[:, 0][None] < m.times[:, 1:]) & (on[:, 1][None] > m.times[:, :1]))
    assert m.orientations == 1
    # the gyroscope drifted and is refreshed to the truth; the accelerometer kept as stored
    gyro = {p.sensor: p for p in r.check.parts}["gyroscope"]
    assert gyro.level == DRIFTED
    assert np.degrees(np.abs(r.gyro.b - truth.gyro.b)).max() < 0.05
    assert not r.check.acc_fit.covered.any()
    np.testing.assert_array_equal(r.acc.b, truth.stored_acc.b)
    np.testing.assert_array_equal(r.acc.K, truth.stored_acc.K)
    assert {c.sensor for c in r.changed} == {"gyroscope"}


def test_a_calibration_that_holds_on_a_flight():
    session, truth = make_everyday("flight", minutes=10, seed=5)
    c = check(calibration(truth), STORED, session)
    parts = {p.sensor: p for p in c.parts}
    assert parts["gyroscope"].level == HOLDS
    assert c.level != DRIFTED


def test_synth_writes_a_flight_and_check_reads_it(tmp_path, capsys):
    rec = tmp_path / "flight.mat"
    assert main(["synth", str(rec), "--activity", "flight", "--minutes", "3", "--seed", "4",
                 "--drift-gyro-bias", "0.5,0,0"]) == 0
    truth = json.loads((tmp_path / "flight.mat.truth.json").read_text())
    assert truth["activity"] == "flight" and len(truth["still_intervals"]) >= 2
    capsys.readouterr()
    rc = main(["check", str(tmp_path / "flight.mat.calib.json"), str(rec), "--json"])
    data = json.loads(capsys.readouterr().out)
    assert rc == 1
    gyro = {p["sensor"]: p for p in data["parts"]}["gyroscope"]
    g = truth["stored"]["gyroscope"]
    seen = (np.array(g["T"]) * np.array(g["K"])[None]) @ [0.5, 0.0, 0.0]  # the stored M4's
    assert gyro["level"] == "drifted"
    for i, a in enumerate("xyz"):
        assert abs(gyro["per_axis"][a]["value"] - seen[i]) < 0.02
    assert main(["synth", str(tmp_path / "x.mat"), "--activity", "plane"]) == 2
