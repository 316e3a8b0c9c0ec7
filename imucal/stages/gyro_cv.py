"""The gyroscope fit (method.md §4: M4, M5) and how well it predicts turns it did not see
(§5): the fit itself, the K-fold held-out angles, and the choice between the still-block bias
and a fitted one that those held-out angles make."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from imucal.errors import ImucalError
from imucal.models import GYRO_THETA0, SensorModel
from imucal.numerics.kfold import fold_of_groups, kfold_refits
from imucal.numerics.least_squares import FitReport, fit_tikhonov
from imucal.numerics.quaternion import rotate_inverse
from imucal.stages.gyro_transitions import Transitions, angle_between, gyro_model_of

# Folds of the cross-validation over turns: K = min(CV_FOLDS, number of turns fitted).
CV_FOLDS = 10

@dataclass(frozen=True)
class GyroCV:
    """Gravity prediction out of sample (method.md §5): each turn predicted by a fit that did
    not see it (K-fold over the turns), and the bias choice made by it (§4).

    ``rms_static_bias`` and ``rms_optimised_bias`` are the RMS held-out angles (deg) of the fit
    with the still-block bias and of the fit that also corrects the bias; ``None`` for a
    variant not fitted (the choice forced by the setting), NaN with too few turns to hold any
    out (``folds`` 0).
    """

    folds: int
    angle: np.ndarray  # (K,) deg, the chosen fit's; NaN for turns left out of the fit
    rms_static_bias: float | None
    rms_optimised_bias: float | None
    optimise_bias: bool  # the bias was fitted (12 parameters), not only measured (9)
    how: str  # "cross-validation", "setting", or "too few turns" (one: none to hold out)

    @property
    def rms(self) -> float:
        """RMS held-out angle of the chosen fit (deg)."""
        rms = self.rms_optimised_bias if self.optimise_bias else self.rms_static_bias
        return float("nan") if rms is None else float(rms)


def fit_bias_choice(tr: Transitions, u_prev: np.ndarray, u_meas: np.ndarray,
                    bias: np.ndarray, s0: float, lam: float, optimise: bool | None
                    ) -> tuple[FitReport, GyroCV]:
    """Fit M4 with the still-block bias (9 parameters) or with a correction of it too (12),
    and say how well each predicts turns it did not see.

    ``optimise`` True or False fits that variant; ``None`` fits both and keeps the one with
    the lower held-out gravity prediction error (K-fold over the turns, K = min(10, turns);
    ties keep the still-block bias, the smaller model). In-sample figures cannot choose: the
    12-parameter fit always fits the turns it saw at least as well. On the real MPU-9150 units
    in ../shared/data the fitted bias halves the held-out error on two (0.32 -> 0.13 deg and
    0.31 -> 0.17 deg) and is slightly worse on the third (0.163 vs 0.173 deg).
    """
    n = len(u_meas)
    n_folds = min(CV_FOLDS, n) if n >= 2 else 0
    folds = fold_of_groups(n, n_folds)
    reports: dict[bool, FitReport] = {}
    rms: dict[bool, float] = {}
    angles: dict[bool, np.ndarray] = {}
    for opt in ([False, True] if optimise is None else [bool(optimise)]):
        theta0 = np.r_[GYRO_THETA0, np.zeros(3)] if opt else GYRO_THETA0.copy()
        start, start_name = theta0, "prior"
        if opt and False in reports:  # the 9-parameter solution with no bias correction
            start, start_name = np.r_[reports[False].theta, np.zeros(3)], "still-bias fit"
        reports[opt] = fit_turns(tr, u_prev, u_meas, bias, s0, theta0, start, lam, start_name)
        angles[opt] = (_held_out_angles(tr, reports[opt], theta0, lam, u_prev, u_meas, bias,
                                        s0, folds, n_folds) if n_folds else np.full(n, np.nan))
        rms[opt] = float(np.sqrt(np.mean(np.square(angles[opt])))) if n else float("nan")
    if optimise is not None:
        chosen, how = bool(optimise), "setting"
    elif n_folds:
        chosen, how = bool(rms[True] < rms[False]), "cross-validation"
    else:  # a single turn: none to hold out, so the smaller model
        chosen, how = False, "too few turns"
    cv = GyroCV(folds=n_folds, angle=angles[chosen], rms_static_bias=rms.get(False),
                rms_optimised_bias=rms.get(True), optimise_bias=chosen, how=how)
    return reports[chosen], cv


def fit_turns(tr: Transitions, u_prev: np.ndarray, u_meas: np.ndarray, bias: np.ndarray, s0: float,
         theta0: np.ndarray, start: np.ndarray, lam: float, start_name: str) -> FitReport:
    """M5's residuals ``u_k - R_k^T u_(k-1)`` minimised with Tikhonov on ``theta - theta0``."""

    def model_of(theta: np.ndarray) -> SensorModel:
        return gyro_model_of(theta, bias, s0)

    def res(theta: np.ndarray) -> np.ndarray:
        # LM asks for the Jacobian where it has just evaluated the residuals (when it accepts
        # the step): one pass over the samples makes both (Transitions.rotations).
        return (u_meas - tr.predict(model_of(theta), u_prev, sensitivity=True)).ravel()

    def jac(theta: np.ndarray) -> np.ndarray:
        return tr.jacobian(model_of, theta, u_prev)

    try:
        return fit_tikhonov(res, jac, start, theta0, lam, start_name=start_name)
    except FloatingPointError:
        # RK4 over steps far longer than a turn (a wrong --rate, a timestamp unit off by 1000)
        # overflows the quaternions: the data, not a bug (issue 27).
        raise ImucalError("the turns cannot be integrated: the predicted gravity is not finite "
                          "at the start of the fit; the sample period is far too long for the "
                          "turns' rates (check --rate or the time column's unit)",
                          source="gyroscope", field="fit") from None


def _held_out_angles(tr: Transitions, report: FitReport, theta0: np.ndarray, lam: float,
                     u_prev: np.ndarray, u_meas: np.ndarray, bias: np.ndarray, s0: float,
                     folds: np.ndarray, n_folds: int) -> np.ndarray:
    """Angle (deg) between each turn's measured gravity direction and its prediction (M5) by
    the fit refitted without the turn's fold (:func:`~imucal.numerics.kfold.kfold_refits`:
    the refits' first Gauss-Newton step from the full fit, as good as refits run to
    convergence here); the predictions are integrated exactly, every turn with its own fold's
    model, in one pass."""
    q = tr.rotations(gyro_model_of(report.theta, bias, s0))
    r = (u_meas - rotate_inverse(q, u_prev)).ravel()
    thetas = kfold_refits(report.jac, r, report.theta, theta0, lam, np.repeat(folds, 3),
                          n_folds)
    models = [gyro_model_of(th, bias, s0) for th in thetas]
    M = np.array([m.matrix for m in models])[folds]
    b = np.array([m.b for m in models])[folds]
    return angle_between(u_meas, rotate_inverse(tr.rotations_each(M, b), u_prev))
