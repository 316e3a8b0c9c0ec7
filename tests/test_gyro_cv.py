"""The nominal model behind the "before" figure of a gyroscope in raw counts (method.md §5)."""

from pathlib import Path

import numpy as np
import pytest

import imucal
from imucal.models import SensorModel
from imucal.numerics.kfold import fold_of_groups, kfold_refits
from imucal.settings import Settings
from imucal.stages.gyro import Transitions, angle_between
from imucal.synth import make_session

ROOT = Path(__file__).resolve().parents[1]


def _shared_data() -> Path:
    """../shared/data beside the checkout, or beside the folder of worktrees holding it."""
    for parent in ROOT.parents[:2]:
        if (parent / "shared" / "data").is_dir():
            return parent / "shared" / "data"
    pytest.skip("../shared/data is not beside the project")


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def _segment_transitions(session, result, seg) -> Transitions:
    b0, b1 = seg.blocks
    return Transitions(session.gyro, session.t_gyro, result.block_times[b0:b1])


# --- the numerics ------------------------------------------------------------------------------


def test_kfold_refits_are_exact_for_a_linear_problem():
    """For residuals linear in theta the one-step refit is the refit: it matches the Tikhonov
    solution on the rows of the other folds solved directly."""
    rng = np.random.default_rng(3)
    n, p, lam = 60, 5, 0.3
    A, y = rng.normal(size=(n, p)), rng.normal(size=n)
    theta0 = rng.normal(size=p)
    theta = np.linalg.solve(A.T @ A + lam * np.eye(p), A.T @ y + lam * theta0)
    folds = fold_of_groups(n // 3, 7)
    rows = np.repeat(folds, 3)
    got = kfold_refits(A, A @ theta - y, theta, theta0, lam, rows, 7)
    for f in range(7):
        Af, yf = A[rows != f], y[rows != f]
        want = np.linalg.solve(Af.T @ Af + lam * np.eye(p), Af.T @ yf + lam * theta0)
        np.testing.assert_allclose(got[f], want, rtol=1e-10, atol=1e-12)


# --- the nominal model ("before") --------------------------------------------------------------


def test_nominal_before_of_a_counts_gyroscope_removes_its_offset():
    """Raw counts sit near 32768 at rest: the nominal model takes the still-block bias off
    before the datasheet's scale, so "before" is the error of the uncalibrated sensor (its
    misalignment and scale errors), not of the offset integrated as a rotation (~95 deg)."""
    per_rad_s = 939.65
    session, truth = make_session(poses=24, seed=5, gyro_unit="counts", acc_unit="counts",
                                  counts_per_rad_s=per_rad_s)
    r = imucal.calibrate(session, Settings(gyro_sensitivity=1 / per_rad_s))
    seg = r.segments[0]
    g = seg.gyro
    # The truth's own uncalibrated sensor: its true bias (offset included), the nominal
    # scale, no misalignment or scale correction.
    nominal = SensorModel(T=np.eye(3), K=np.full(3, 1 / per_rad_s), b=truth.gyro.b)
    tr = _segment_transitions(session, r, seg)
    true_before = _rms(angle_between(g.u_meas, tr.predict(nominal, g.u_prev)))
    before, after = r.quality.gravity_angle_rms_deg
    assert 1.0 < true_before < 10.0
    assert before == pytest.approx(true_before, rel=0.02)
    assert after < before / 20


def test_xsens_before_with_a_datasheet_sensitivity(tmp_path):
    d = _shared_data() / "imu_tk_xsens"
    session = imucal.load_session(d / "xsens_acc.mat", gyro_path=d / "xsens_gyro.mat")
    assert session.gyro_unit == "counts"
    # A 16-bit gyroscope of about +-390 deg/s full scale; the data's own scale is 2.096e-4.
    r = imucal.calibrate(session, Settings(gyro_sensitivity=2.1e-4))
    before, after = r.quality.gravity_angle_rms_deg
    assert before < 5.0  # was 94.9 with the offset left in
    assert after < before / 5
