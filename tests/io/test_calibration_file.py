"""The calibration file: a symmetric API (to_dict / from_dict), a save -> load -> apply round
trip, the migration hook for future format versions, and refusals of damaged files."""

from __future__ import annotations

import json

import numpy as np
import pytest

import imucal
from imucal.errors import ImucalError
from imucal.io import calibration_file as cf
from imucal.stages.apply import Calibration
from imucal.synth import make_session


@pytest.fixture(scope="module")
def run():
    session, _ = make_session(poses=24, seed=11, change_at=0.5, acc_change=(0.02, 0.03))
    return session, imucal.calibrate(session)


def test_to_dict_from_dict_round_trip(run):
    _, result = run
    cal = result.calibration
    back = Calibration.from_dict(json.loads(json.dumps(cal.to_dict())))
    assert back.acc_unit_raw == cal.acc_unit_raw and back.gyro_unit_raw == cal.gyro_unit_raw
    assert back.g == cal.g and len(back.segments) == len(cal.segments) == 2
    for a, b in zip(cal.segments, back.segments):
        assert (a.t_start, a.t_end) == (b.t_start, b.t_end)
        for m, n in ((a.acc, b.acc), (a.gyro, b.gyro)):
            np.testing.assert_array_equal(m.T, n.T)
            np.testing.assert_array_equal(m.K, n.K)
            np.testing.assert_array_equal(m.b, n.b)


def test_save_load_apply_gives_the_run_s_own_signal(run, tmp_path):
    session, result = run
    imucal.save_calibration(result, tmp_path / "c.json")
    applied = imucal.load_calibration(tmp_path / "c.json").apply(session)
    # Two segments: the samples between them get the mean of both (method.md §2), the same
    # arithmetic through the file as in the run.
    np.testing.assert_array_equal(applied.acc, result.calibrated.acc)
    np.testing.assert_array_equal(applied.gyro, result.calibrated.gyro)
    # The bare calibration (no run behind it) is a file apply reads too.
    bare = cf.calibration_to_dict(result.calibration)
    (tmp_path / "bare.json").write_text(json.dumps(bare))
    again = imucal.load_calibration(tmp_path / "bare.json").apply(session)
    np.testing.assert_array_equal(again.acc, result.calibrated.acc)


def test_a_future_version_migrates_an_old_file(run, monkeypatch):
    _, result = run
    v2 = cf.calibration_to_dict(result.calibration)
    assert v2["format_version"] == cf.FORMAT_VERSION == 2

    def v2_to_v3(d: dict) -> dict:  # e.g. version 3 renames |g| to "gravity"
        d = dict(d)
        d["units"] = dict(d["units"])
        d["units"]["gravity"] = d["units"].pop("g")
        return d

    def v3_from_dict(d: dict) -> Calibration:
        d = dict(d)
        d["units"] = dict(d["units"])
        d["units"]["g"] = d["units"].pop("gravity")
        return original(d)

    original = Calibration.from_dict
    monkeypatch.setattr(cf, "FORMAT_VERSION", 3)
    monkeypatch.setitem(cf.MIGRATIONS, 2, v2_to_v3)
    monkeypatch.setattr(Calibration, "from_dict", staticmethod(v3_from_dict))
    migrated = cf.migrate(json.loads(json.dumps(v2)))
    assert migrated["format_version"] == 3 and "gravity" in migrated["units"]
    cal = cf.calibration_from_dict(json.loads(json.dumps(v2)))
    assert cal.g == result.calibration.g
    # A version-1 file goes through both steps.
    v1 = json.loads(json.dumps(v2)) | {"format_version": 1}
    assert cf.migrate(v1)["format_version"] == 3
    with pytest.raises(ImucalError, match="format_version 4 is not supported"):
        cf.migrate(v2 | {"format_version": 4}, "x.json")


def test_a_version_1_file_numbers_its_segments_from_1_once_loaded(run, tmp_path):
    """Version 1 wrote a warning's segment as its 0-based position; version 2 numbers segments
    from 1 everywhere. An old file still loads, applies the same, and reads the same numbers."""
    session, result = run
    imucal.save_calibration(result, tmp_path / "c.json")
    v2 = json.loads((tmp_path / "c.json").read_text())
    assert v2["format_version"] == 2 and "verdict" in v2
    v1 = v2 | {"format_version": 1, "warnings": [
        {"code": "gyro_rotations_saturated", "segment": 0, "message": "m"},
        {"code": "few_orientations", "segment": 1, "message": "m"},
        {"code": "input", "segment": None, "message": "m"}]}
    del v1["verdict"]
    migrated = cf.migrate(json.loads(json.dumps(v1)))
    assert [w["segment"] for w in migrated["warnings"]] == [1, 2, None]
    assert migrated["format_version"] == 2 and "verdict" not in migrated
    (tmp_path / "old.json").write_text(json.dumps(v1))
    np.testing.assert_array_equal(imucal.load_calibration(tmp_path / "old.json").apply(
        session).acc, result.calibrated.acc)


@pytest.mark.parametrize("damage, field", [
    (lambda d: d["segments"][0]["accelerometer"].update(K=[1.0, 0.0, 1.0]),
     "segments[0].accelerometer"),
    (lambda d: d["segments"][1]["gyroscope"].update(T=[[1, 0, 0], [0, 1, 0], [0, 0, 0]]),
     "segments[1].gyroscope"),
    (lambda d: d["units"].update(g=-1.0), "units.g"),
    (lambda d: d.update(format_version=True), "format_version"),
])
def test_damaged_calibrations_are_refused_by_field(run, tmp_path, damage, field):
    _, result = run
    d = cf.calibration_to_dict(result.calibration)
    damage(d)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(d))
    with pytest.raises(ImucalError) as e:
        imucal.load_calibration(path)
    assert e.value.source == str(path) and e.value.field == field
