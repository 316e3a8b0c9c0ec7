"""Quality figures that cannot flatter (method.md §5): each still block predicted by the
accelerometer fit that did not see it."""

from __future__ import annotations

import json

import numpy as np
import pytest

import imucal
from imucal.settings import Settings
from imucal.stages.accel import calibrate_accelerometer
from imucal.stages.accel_cv import leave_one_block_out
from imucal.synth import make_session


def _norm_error_mg(model, mean_raw: np.ndarray) -> float:
    return float((np.linalg.norm(model.apply(mean_raw[None]), axis=1)[0] - 1.0) * 1e3)


@pytest.mark.parametrize("points", ["mean", "ml"])
def test_held_out_prediction_equals_a_refit_without_the_block(points):
    s, _ = make_session(poses=16, seed=3)
    r = imucal.calibrate(s, single_segment=True, points=points)
    fit, det = r.whole, r.detection
    cv = leave_one_block_out(fit, det.means)
    settings = Settings(points=points, lam=fit.lam).acc
    for k in (0, 5, len(det.blocks) - 1):
        keep = np.delete(det.blocks, k, axis=0)
        refit = calibrate_accelerometer(s.acc, keep, acc_unit="g", g_in=1.0, g_out=1.0,
                                        settings=settings, nominal=fit.nominal)
        direct = _norm_error_mg(refit.model, det.means[k])
        # One Gauss-Newton step from the full fit against a refit run to convergence (whose
        # ML weights also move a little without the block): the same to a few microg.
        assert cv.block_error_mg[k] == pytest.approx(direct, abs=0.01 + 0.05 * abs(direct))
    in_sample = [_norm_error_mg(fit.model, m) for m in det.means]
    np.testing.assert_allclose(cv.in_sample_error_mg, in_sample, atol=1e-9)


def test_few_orientations_are_reported_as_overfitted(tmp_path):
    s, _ = make_session(poses=10, seed=0)
    r = imucal.calibrate(s)
    q = r.quality
    assert q.static_norm_cv_mg > 5 * q.static_norm_rms_mg.after
    (w,) = [w for w in r.warnings if w.code == "acc_overfitted"]
    cv = r.segments[0].acc_cv
    assert f"{cv.rms_mg:.3g} mg" in w.message and "directions have no pose" in w.message
    assert 0.5 < cv.coverage < 0.95 and len(cv.uncovered) > 0
    imucal.save_calibration(r, tmp_path / "c.json")
    saved = json.loads((tmp_path / "c.json").read_text())["quality"]
    assert saved["static_norm_rms_mg"]["cross_validated"] == pytest.approx(q.static_norm_cv_mg)
    assert saved["gravity_angle_rms_deg"]["cross_validated"] == pytest.approx(
        q.gravity_angle_cv_deg)


def test_a_well_spread_session_is_not_called_overfitted():
    s, _ = make_session(poses=30, seed=1)
    r = imucal.calibrate(s)
    q = r.quality
    assert not any(w.code == "acc_overfitted" for w in r.warnings)
    # Held-out blocks are predicted a little worse than the fitted ones, never better on the
    # whole: the in-sample figure is the optimistic one.
    assert q.static_norm_rms_mg.after < q.static_norm_cv_mg < 2 * q.static_norm_rms_mg.after
    cv = r.segments[0].acc_cv
    assert cv.coverage > 0.95
    # A well-posed fit's held-out residuals exceed its own by B / (B - p), p its effective
    # number of parameters: the optimism the in-sample figure has anyway.
    assert cv.rms_mg / cv.in_sample_rms_mg == pytest.approx(cv.expected_ratio, rel=0.25)
