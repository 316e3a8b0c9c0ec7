"""The verdict (imucal.stages.verdict): the held-out figures against the thresholds, the
parameters the poses cannot determine, the guide; the worst finding decides and names the
next step. On figures made to sit either side of each threshold, and on a real run."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

import imucal
from imucal.io.calibration_file import result_to_dict
from imucal.stages import verdict as V
from imucal.stages.accel_cv import AccCrossValidation
from imucal.synth import make_session


def _cv(held_mg: float, in_mg: float, undetermined: tuple[str, ...] = (),
        blocks: int = 30) -> AccCrossValidation:
    return AccCrossValidation(block_error_mg=np.full(blocks, held_mg),
                              in_sample_error_mg=np.full(blocks, in_mg),
                              undetermined=undetermined, uncovered=np.zeros((0, 3)),
                              coverage=1.0, expected_ratio=1.3)


def _seg(held_mg: float, in_mg: float, number: int | None = None, orientations: int = 30,
         undetermined: tuple[str, ...] = (), gyro=None) -> V.SegmentFigures:
    return V.SegmentFigures(number, _cv(held_mg, in_mg, undetermined), gyro, orientations)


@pytest.mark.parametrize("held, level, code", [
    (0.3, V.GOOD, "good"),
    (V.ACC_CAVEAT_MG * 0.99, V.GOOD, "good"),
    (V.ACC_CAVEAT_MG * 1.01, V.CAVEATS, "acc_held_out"),
    (V.ACC_POOR_MG * 0.99, V.CAVEATS, "acc_held_out"),
    (V.ACC_POOR_MG * 1.01, V.NOT_USABLE, "acc_held_out"),
])
def test_the_held_out_static_error_sets_the_level(held, level, code):
    # In-sample close to held out: not overfitted, so only the size of the error decides.
    v = V.judge([_seg(held, held / 1.2)], None)
    assert (v.level, v.code) == (level, code)
    assert v.usable is (level != V.NOT_USABLE)
    assert v.figures["acc_held_out_mg"] == pytest.approx(held)
    if level != V.GOOD:
        assert f"off by {held:.3g} mg" in v.reason and "overfitted" not in v.reason


def test_overfitting_alone_is_a_caveat_and_says_so():
    v = V.judge([_seg(0.9, 0.1)], None)  # 9 x in-sample, small in absolute terms
    assert v.level == V.CAVEATS and v.code == "acc_overfitted"
    assert v.reason.startswith("overfitted: still poses the fit did not see are off by 0.9 mg, "
                               "against 0.1 mg on those it saw")


def test_the_worst_finding_decides_and_names_its_segment():
    segs = [_seg(0.3, 0.25, number=1), _seg(12.0, 0.2, number=2, orientations=7,
                                            undetermined=("a_zx",))]
    v = V.judge(segs, None)
    assert v.level == V.NOT_USABLE and v.code == "acc_held_out"
    assert v.reason == ("segment 2: overfitted: still poses the fit did not see are off by "
                        "12 mg, against 0.2 mg on those it saw: 7 distinct orientations (9 "
                        "needed) leave a_zx undetermined")
    assert v.next_step.startswith("record ") and "more poses" in v.next_step
    assert [c.code for c in v.caveats] == ["acc_undetermined", "few_orientations"]
    assert all(c.reason.startswith("segment 2: ") for c in v.caveats)
    assert set(v.figures) == {f"segment_{n}_{k}" for n in (1, 2)
                              for k in ("acc_held_out_mg", "acc_in_sample_mg")}
    # Two good segments: the reason gives the worse one's figure.
    ok = V.judge([_seg(0.3, 0.25, number=1), _seg(0.7, 0.6, number=2)], None)
    assert ok.level == V.GOOD and ok.reason == "still poses the fit did not see are off by 0.7 mg"


def test_a_maker_spec_makes_an_out_of_spec_unit_not_usable():
    good = V.judge([_seg(0.3, 0.25)], None)
    passed = V.with_spec(good, {"pass": True, "broken": [], "unchecked": []}, "lim.toml")
    assert passed.level == V.GOOD and passed.to_dict()["spec"]["file"] == "lim.toml"
    check = {"pass": False, "broken": ["acc_bias_mg: b_x = 120 mg (limit 40)",
                                       "acc_scale_pct: s_y = 4 % (limit 3)"], "unchecked": []}
    v = V.with_spec(good, check, "lim.toml")
    assert v.level == V.NOT_USABLE and v.code == "out_of_spec" and not v.usable
    assert v.reason == ("out of the limits of lim.toml: acc_bias_mg: b_x = 120 mg (limit 40) "
                        "(and 1 more)")
    assert v.caveats[0].level == V.GOOD and v.caveats[0].reason == good.reason
    assert v.to_dict()["spec"]["broken"] == check["broken"]


@pytest.fixture(scope="module")
def run():
    session, _ = make_session(poses=30, seed=21)
    return imucal.calibrate(session)


def test_a_good_synthetic_run_and_its_gyroscope_thresholds(run):
    v = run.verdict
    assert v.level == V.GOOD and v.code == "good" and v.caveats == ()
    seg = run.segments[0]
    assert v.figures["gravity_held_out_deg"] == pytest.approx(seg.gyro.cv.rms)
    assert v.figures["acc_held_out_mg"] == pytest.approx(seg.acc_cv.rms_mg)
    # The same gyroscope fit, its held-out error moved either side of the thresholds.
    for held, level in ((V.GYRO_CAVEAT_DEG * 1.01, V.CAVEATS),
                        (V.GYRO_POOR_DEG * 1.01, V.NOT_USABLE)):
        cv = dataclasses.replace(seg.gyro.cv, rms_static_bias=held, rms_optimised_bias=held)
        fit = dataclasses.replace(seg.gyro, cv=cv)
        w = V.judge([V.SegmentFigures(None, seg.acc_cv, fit, seg.orientations)], run.guide)
        assert (w.level, w.code) == (level, "gyro_held_out")
        assert f"end {held:.2g} deg off" in w.reason and w.next_step.startswith("record more")


def test_calibration_file_holds_the_verdict_at_the_top_level(run):
    d = json.loads(json.dumps(result_to_dict(run)))
    assert d["verdict"] == json.loads(json.dumps(run.verdict.to_dict()))
    assert d["verdict"]["level"] == "good" and d["verdict"]["next"] == run.verdict.next_step
    assert d["verdict"]["thresholds"]["acc_held_out_mg"] == {"caveats": V.ACC_CAVEAT_MG,
                                                              "not_usable": V.ACC_POOR_MG}
    assert list(d)[-1] == "verdict" and d["format_version"] == 2


def test_undetermined_parameters_make_good_figures_not_usable():
    # Figures well inside every limit (a coplanar session's): no held-out pose saw the
    # direction the undetermined parameters govern, so they decide (issue 27).
    v = V.judge([_seg(0.2, 0.18, undetermined=("s_x", "b_x"))], None)
    assert v.level == V.NOT_USABLE and v.code == "acc_undetermined" and not v.usable
    assert v.reason.startswith("the still poses do not determine s_x, b_x: kept near the "
                               "nominal value, not measured; a pose along the directions")
    assert f"more than {V.ACC_POOR_MG:g} mg" in v.reason
