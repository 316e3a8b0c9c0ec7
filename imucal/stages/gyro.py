"""Gyroscope calibration (method.md §4: M4, M5)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from imucal.errors import ImucalError, plural
from imucal.models import GYRO_PARAM_NAMES, SensorModel, gyro_theta
from imucal.numerics.determinacy import determinacy
from imucal.numerics.directions import DISTINCT_ANGLE_DEG
from imucal.numerics.least_squares import (
    FactoredCov,
    FitReport,
    trace_of,
)
from imucal.numerics.quaternion import rotate_inverse, to_matrix
from imucal.numerics.windows import segment_sums
from imucal.settings import GyroSettings, Settings
from imucal.stages.gyro_cv import GyroCV, fit_bias_choice
from imucal.stages.gyro_transitions import (
    Transitions,
    angle_between,
    gyro_model_of,
    sorted_position,
)
from imucal.stages.saturation import blocks_with
from imucal.warning import RunWarning

# Rotation per gyroscope sample M5's integrator (RK4, the rate at a half step the mean of the
# neighbours) carries without visible error. Measured with imucal.synth turns (minimum jerk,
# true model, no noise): the gravity prediction error at 100 Hz is 0.0009 deg median at 8 deg
# per sample, 0.005 at 12.6 and 0.07 at 31 (140 Hz: 0.0018 deg at 9 deg per sample); 10 deg per
# sample keeps it near 0.01 deg, far below a good fit's 0.05-0.1 deg.
MAX_STEP_DEG = 10.0


def small_turns_text(n_small: int, n: int) -> str:
    """The one sentence for turns that move gravity less than DISTINCT_ANGLE_DEG: the
    gyroscope fit's warning and the guide's (imucal.stages.guide.MIN_TILT_DEG) say it alike."""
    return (f"{n_small} of {n} turns move gravity less than {DISTINCT_ANGLE_DEG:g} deg: they "
            "land in the same pose and tell the gyroscope little")


# Held-out error this many times the in-sample one is said to be overfitting (method.md §5).
# Measured: 1.1 to 1.4 on the real recordings in ../shared/data.
OVERFIT_RATIO = 2.0
# A misalignment or scale the turns alone pin no better than this is undetermined (issue 27):
# off by that much, a 90-deg turn about the axis it governs ends 3 deg off gravity, the
# verdict's not-usable limit (imucal.stages.verdict.GYRO_POOR_DEG); a fitted bias, when it
# would turn the device 3 deg over the session's median turn. Measured: 1e-4 on well-posed
# synthetic sessions and the sample; 0.2-0.5 for what a session of turns about one axis leaves.
UNDETERMINED_TURN_DEG = 3.0


@dataclass(frozen=True)
class GyroFit:
    model: SensorModel  # w = T_g K_g (w_raw - b_g), w in rad/s
    std: np.ndarray  # standard errors of (g_yz, g_zy, g_xz, g_zx, g_xy, g_yx, s_x, s_y, s_z[, b])
    bias_source: str
    nominal_scale: float
    nominal_how: str
    lam: float
    report: FitReport
    u_prev: np.ndarray  # (K, 3) measured gravity direction of the block before each transition
    u_meas: np.ndarray  # (K, 3) measured gravity direction of the block after it
    u_pred_before: np.ndarray | None  # (K, 3) predicted by the uncalibrated gyroscope
    u_pred_after: np.ndarray  # (K, 3) predicted by the calibrated gyroscope
    t_transition: np.ndarray  # (K, 2) [t_start, t_end] of each transition
    rotation_angle: np.ndarray  # (K,) integrated rotation angle, rad
    static_bias: np.ndarray  # (3,) the bias measured on the still blocks, raw units
    excluded: np.ndarray  # (K,) bool: transitions left out of the fit (saturated samples, or
    # no gyroscope data: see imucal.stages.sanity)
    cv: GyroCV  # the same prediction out of sample, and the bias choice
    warnings: list[RunWarning] = field(default_factory=list)
    undetermined: tuple[str, ...] = ()  # parameters the turns do not determine (std NaN)

    def model_for(self, theta: np.ndarray) -> SensorModel:
        """The raw-unit model of any parameter vector of the fit (a step of its trace): scales
        relative to the nominal scale, and an optimised bias a correction in nominal rad/s on
        top of the static one (M4)."""
        return gyro_model_of(theta, self.static_bias, self.nominal_scale)

    @property
    def params(self) -> np.ndarray:
        """(9,) misalignments and scales of the solution (``GYRO_PARAM_NAMES``); the bias is
        ``model.b``."""
        return gyro_theta(self.model)

    @property
    def param_names(self) -> tuple[str, ...]:
        """Names of ``std``: the 9 of M4, and the bias when it was optimised."""
        return GYRO_PARAM_NAMES + (("b_x", "b_y", "b_z") if len(self.std) > 9 else ())

    @property
    def trace_params(self) -> np.ndarray:
        """(I, 9) :attr:`params` at each accepted step of the fit (``report.trace_theta``, what
        the optimiser's report records)."""
        return np.array([gyro_theta(self.model_for(th))
                         for th in self.report.trace_theta]).reshape(-1, 9)

    @property
    def trace_bias(self) -> np.ndarray:
        """(I, 3) the raw-unit bias at each accepted step (constant unless optimised)."""
        return np.array([self.model_for(th).b for th in self.report.trace_theta]).reshape(-1, 3)

    def nominal_rate(self, w_raw: np.ndarray, unit: str) -> np.ndarray:
        """The raw rate in nominal rad/s, uncalibrated, to set beside the calibrated one: the
        signal itself for input in rad/s; raw counts (which carry an ADC offset) less the bias,
        times the nominal scale."""
        if unit != "counts":
            return w_raw
        return (w_raw - self.model.b) * self.nominal_scale

    @property
    def u_blocks(self) -> np.ndarray:
        """(K+1, 3) measured gravity direction of every still block of the segment."""
        return np.vstack([self.u_prev[:1], self.u_meas])

    @property
    def angle_before(self) -> np.ndarray | None:
        return None if self.u_pred_before is None else angle_between(self.u_meas,
                                                                     self.u_pred_before)

    @property
    def angle_after(self) -> np.ndarray:
        return angle_between(self.u_meas, self.u_pred_after)


def static_bias(w_raw, t, block_times: np.ndarray, how: str) -> tuple[np.ndarray, str]:
    """Gyroscope bias from the still periods (method.md §4): the samples of each block are
    those of :func:`~imucal.numerics.windows.samples_within` (the product's one convention).
    ``w_raw`` and ``t`` are read by gathers and a slice of rows a block (they may be arrays
    kept on disk)."""
    times = np.asarray(block_times, dtype=float).reshape(-1, 2)
    lo = sorted_position(t, times[:, 0], side="left")
    hi = np.maximum(sorted_position(t, times[:, 1], side="right"), lo)
    ok = (hi - lo) >= 2
    if not ok.any():
        raise ImucalError("no gyroscope samples fall inside the static blocks; check that the "
                          "accelerometer and gyroscope timestamps share one clock",
                          source="gyroscope", field="timestamps")
    lo, hi = lo[ok], hi[ok]
    if how == "first":
        return w_raw[lo[0]:hi[0]].mean(axis=0), "mean of the first static block (thesis)"
    if how != "all":
        raise ImucalError(f"unknown gyroscope bias source {how!r}; expected 'all' or 'first'",
                          source="settings", field="gyro_bias")
    # each block's sum as segment_sums makes it over the whole signal (its own range only)
    sums = np.array([segment_sums(w_raw[a:b], np.zeros(1, np.int64), np.full(1, b - a))[0]
                     for a, b in zip(lo, hi)])
    n = int((hi - lo).sum())
    return sums.sum(axis=0) / n, f"mean over all {plural(len(lo), 'static block')} ({n} samples)"


def _find_scale(tr: Transitions, bias: np.ndarray, u_prev: np.ndarray, u_meas: np.ndarray
                ) -> float:
    """Data-driven nominal scale for a gyroscope in raw counts: the isotropic scale s that
    best carries each gravity direction into the next, so no hand-set guess is needed.

    The angle between consecutive gravity directions is at most the angle turned, which is at
    most ``s`` times the integral of the raw rate's norm: their ratio brackets ``s`` from
    below. A log grid around that estimate, then a bounded 1-D refinement, finds the minimum
    of the M5 cost; with no usable rotation the grid spans eight decades.
    """

    def costs(log_s: np.ndarray) -> np.ndarray:
        # |u_meas - tr.predict(SensorModel(I, exp(log_s), bias), u_prev)|^2 of each scale, a
        # group of scales integrated in one pass (groups of 16: the rotations of the 160-point
        # grid at once would be 160 K quaternions)
        out = []
        for group in np.array_split(log_s, -(-len(log_s) // 16)):
            q = tr.rotations_many([SensorModel(T=np.eye(3), K=np.full(3, np.exp(g)), b=bias)
                                   for g in group])
            r = u_meas - rotate_inverse(q, u_prev)
            out.append(np.sum(r * r, axis=(1, 2)))
        return np.concatenate(out)

    turned = np.radians(angle_between(u_prev, u_meas))
    raw_turn = tr.raw_turn(bias)
    ok = (turned > np.radians(10.0)) & (raw_turn > 0)
    if ok.any():
        est = float(np.median(turned[ok] / raw_turn[ok]))
        # Steps of 19 %: a rotation of angle a aliases only when the scale is off by about
        # 2 pi / a, so the basin of the right scale spans many steps (13 points, not 25:
        # each point is a whole integration).
        grid = np.linspace(np.log(est / 2.0), np.log(est * 4.0), 13)
    else:
        grid = np.linspace(np.log(1e-7), np.log(10.0), 160)
    i = int(np.argmin(costs(grid)))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    from scipy.optimize import minimize_scalar  # here, where it runs (see fit_tikhonov)

    best = minimize_scalar(lambda g: float(costs(np.array([g]))[0]), bounds=(lo, hi),
                           method="bounded", options={"xatol": 1e-6})
    return float(np.exp(best.x))


def _excluded_turns(tr: Transitions, saturated: np.ndarray | None, no_data: np.ndarray | None,
                    warnings: list[RunWarning]) -> np.ndarray:
    """(K,) True for the turns left out of the fit: through saturated samples (said in
    ``warnings``) or without gyroscope data; refused when none is left."""
    excluded = np.zeros(len(tr), dtype=bool)
    if saturated is not None and np.any(saturated):
        excluded = blocks_with(saturated, np.column_stack([tr.starts, tr.ends + 1]))
        if excluded.all():
            raise ImucalError(f"all {len(excluded)} rotations between still poses pass through "
                              "saturated gyroscope samples (flat at the sensor's limit): turn "
                              "more slowly", source="gyroscope", field="rotations")
        warnings.append(RunWarning("gyro_rotations_saturated", f"{int(excluded.sum())} of "
                                   f"{len(excluded)} rotations between still poses pass through "
                                   "saturated gyroscope samples and are left out of the "
                                   "gyroscope fit"))
    if no_data is not None and np.any(no_data):
        excluded = excluded | no_data
        if excluded.all():
            raise ImucalError(f"none of the {len(excluded)} rotations between still poses has "
                              "usable gyroscope data (no samples, a time gap or saturation)",
                              source="gyroscope", field="rotations")
    return excluded


def _nominal_scale(tr: Transitions, bias: np.ndarray, u_prev: np.ndarray, u_meas: np.ndarray,
                   gyro_unit: str, settings: GyroSettings) -> tuple[float, str]:
    """The nominal scale s0 of M4 (rad/s per input unit) and where it came from."""
    if gyro_unit != "counts":
        return 1.0, "input in rad/s"
    if settings.nominal_scale:
        return float(settings.nominal_scale), "given sensitivity"
    return _find_scale(tr, bias, u_prev, u_meas), "1-D search on the data (counts)"


def calibrate_gyroscope(w_raw: np.ndarray, t: np.ndarray, block_times: np.ndarray,
                        gravity: np.ndarray, gyro_unit: str,
                        settings: GyroSettings = Settings().gyro,
                        gravity_cov: np.ndarray | FactoredCov | None = None,
                        saturated: np.ndarray | None = None,
                        no_data: np.ndarray | None = None,
                        bias: tuple[np.ndarray, str] | None = None) -> GyroFit:
    """Fit M4 so that integrating the calibrated rate (M5) turns each block's gravity
    direction into the next one's.

    ``block_times`` (B, 2) are the static blocks in seconds and ``gravity`` (B, 3) their mean
    calibrated accelerations, with ``gravity_cov`` (3B, 3B) their covariance when known (see
    :func:`direction_error_cov`). ``saturated`` (N,) marks gyroscope samples flat at the
    sensor's limit: a rotation through them is under-measured by any calibration, so its
    transition is left out of the fit (and of the quality figure), but still predicted and shown.
    ``no_data`` (K,) marks transitions the gyroscope does not cover (before its first sample,
    after its last, across a time gap): left out the same way (the caller says which).
    Whether the bias is fitted too is ``settings.optimise_bias``, or with ``None`` the variant
    that predicts held-out turns better (:func:`fit_bias_choice`).

    ``w_raw`` (N, 3) and ``t`` (N,) are read only by ``len``, ``.shape``, slices of rows and
    gathers with a 1-D integer array, never whole (they may be arrays kept on disk; issue 12).
    ``bias`` (the still bias and its source) stands for :func:`static_bias` where the still
    samples are not in ``w_raw`` (a live capture keeps the turns only, method.md §13).
    """
    if len(block_times) < 2:
        raise ImucalError(f"{plural(len(block_times), 'static block')}: the gyroscope needs at "
                          "least two still poses with a rotation between them", source="gyroscope",
                          field="static blocks")
    warnings: list[RunWarning] = []
    u = gravity / np.linalg.norm(gravity, axis=1, keepdims=True)
    bias, bias_source = (static_bias(w_raw, t, block_times, settings.bias) if bias is None
                         else bias)
    tr_all = Transitions(w_raw, t, block_times)
    excluded = _excluded_turns(tr_all, saturated, no_data, warnings)
    keep = ~excluded
    tr = tr_all if keep.all() else Transitions(w_raw, t, block_times, keep)
    fit_prev, fit_meas = u[:-1][keep], u[1:][keep]

    s0, how = _nominal_scale(tr, bias, fit_prev, fit_meas, gyro_unit, settings)
    have_nominal = gyro_unit != "counts" or bool(settings.nominal_scale)

    report, cv = fit_bias_choice(tr, fit_prev, fit_meas, bias, s0, settings.lam,
                                 settings.optimise_bias)
    if cv.optimise_bias:  # the model's bias is no longer the still-block mean alone
        bias_source += (", then fitted (set by optimise_gyro_bias)" if cv.how == "setting"
                        else ", then fitted (chosen by cross-validation)")
    if not keep.all():
        angle_cv = np.full(len(tr_all), np.nan)
        angle_cv[keep] = cv.angle
        cv = dataclasses.replace(cv, angle=angle_cv)
    model = gyro_model_of(report.theta, bias, s0)
    q_model = tr_all.rotations(model)  # integrated once, used three times below
    turn_s = float(np.median(t[tr_all.ends] - t[tr_all.starts])) if len(tr_all) else 1.0
    std, weak = _standard_errors(report, gravity, gravity_cov, q_model, keep, s0, turn_s)

    u_prev, u_meas = u[:-1], u[1:]  # every transition, the excluded ones too
    before = None
    if have_nominal:
        # The nominal model: still-block bias, then the nominal scale. A gyroscope in raw
        # counts has no zero of its own (a 16-bit one rests near 32768 counts), so its "before"
        # needs the bias removed; one in rad/s is judged as it comes, bias and all.
        b0 = bias if gyro_unit == "counts" else np.zeros(3)
        before = tr_all.predict(SensorModel(T=np.eye(3), K=np.full(3, s0), b=b0), u_prev)
    after = rotate_inverse(q_model, u_prev)  # = tr_all.predict(model, u_prev)
    angle = 2 * np.degrees(np.arccos(np.clip(np.abs(q_model[:, 0]), 0, 1)))
    in_sample = angle_between(u_meas, after)[keep]
    # Judged on the turns fitted: one without data turns by nothing, one across a gap in a step.
    warnings += _fit_warnings(tr, model, report, angle_between(u_meas, u_prev)[keep],
                              in_sample, cv)
    if weak:
        warnings.append(RunWarning(
            "gyro_undetermined", f"the turns do not determine the gyroscope's "
            f"{', '.join(weak)}: kept near the nominal value, not measured (no standard error "
            "given); turns it did not see cannot show it either, as none turned about the axes "
            "they govern: record turns about every axis"))
    return GyroFit(model=model, std=std, bias_source=bias_source, nominal_scale=s0,
                   nominal_how=how, lam=settings.lam, report=report, u_prev=u_prev,
                   u_meas=u_meas, u_pred_before=before, u_pred_after=after,
                   t_transition=np.column_stack([t[tr_all.starts], t[tr_all.ends]]),
                   rotation_angle=np.radians(angle), static_bias=bias, excluded=excluded,
                   cv=cv, warnings=warnings, undetermined=weak)


def _standard_errors(report: FitReport, gravity: np.ndarray,
                     gravity_cov: np.ndarray | FactoredCov | None, q_model: np.ndarray,
                     keep: np.ndarray, s0: float, turn_s: float
                     ) -> tuple[np.ndarray, tuple[str, ...]]:
    """Standard errors of the parameters in raw units from the turns alone (the prior is no
    measurement: :mod:`imucal.numerics.determinacy`), with the measured gravity's own errors
    in the residuals' covariance when they are known (:func:`direction_error_cov`); NaN for
    the parameters they leave undetermined (UNDETERMINED_TURN_DEG), which are named.
    ``turn_s`` is the median turn's duration, s."""
    n, p = report.jac.shape
    s2, meat = report.data_cost / max(n - p, 1), None
    if gravity_cov is not None:
        meat = direction_error_cov(gravity, gravity_cov, to_matrix(q_model))
        if not keep.all():
            meat = (meat.select(keep) if isinstance(meat, FactoredCov)
                    else np.asarray(meat)[np.ix_(np.repeat(keep, 3), np.repeat(keep, 3))])
        # Each residual is the difference of two unit vectors: only its 2 components across
        # u_k carry error to first order, so a transition gives 2 degrees of freedom, not 3.
        s2 = max(report.data_cost - trace_of(meat), 0.0) / max(2 * n // 3 - p, 1)
    angle = np.radians(UNDETERMINED_TURN_DEG)
    limits = np.r_[np.full(9, angle / (np.pi / 2)), np.full(p - 9, angle / max(turn_s, 1e-9))]
    names = GYRO_PARAM_NAMES + ("b_x", "b_y", "b_z")[:p - 9]
    det = determinacy(report.jac, s2, names, limits, meat)
    std = det.std.copy()
    std[6:9] *= s0
    if len(std) > 9:
        std[9:12] /= s0
    return std, det.undetermined


def _fit_warnings(tr_all: Transitions, model: SensorModel, report: FitReport,
                  tilt: np.ndarray, in_sample: np.ndarray, cv: GyroCV) -> list[RunWarning]:
    """What a user should know about the gyroscope fit (``tilt``: degrees each fitted turn
    moved gravity; ``in_sample``: the fitted transitions' gravity prediction error, deg)."""
    warnings = []
    if np.any(model.K <= 0):
        warnings.append(RunWarning("gyro_scale_not_positive", "gyroscope fit reached a "
                                   "non-positive scale: the result is not physical"))
    elif np.any(np.abs(report.theta[6:9] - 1) > 0.5):
        warnings.append(RunWarning("gyro_scale_far", f"gyroscope scales "
                                   f"{np.round(report.theta[6:9], 3).tolist()} (nominal frame) "
                                   "are far from 1: check the gyroscope unit"))
    if report.cost > report.cost_start * (1 + 1e-9):
        warnings.append(RunWarning("gyro_cost_rose", "gyroscope fit ended with a higher cost "
                                   "than it started from"))
    per_step = tr_all.max_step_angle(model)
    if per_step > np.radians(MAX_STEP_DEG):
        warnings.append(RunWarning("gyro_rotations_fast", f"rotations too fast for the "
                                   f"gyroscope's sample rate: up to {np.degrees(per_step):.0f} "
                                   "degrees between two samples; the integration loses "
                                   f"accuracy above about {MAX_STEP_DEG:g}: turn more slowly"))
    # A turn that hardly moves gravity lands in the same pose: M5 sees nothing of a rotation
    # about gravity, so the tilt decides, with the guide's threshold (one for both).
    small = np.count_nonzero(tilt < DISTINCT_ANGLE_DEG)
    if small:
        warnings.append(RunWarning("gyro_rotations_small", small_turns_text(small, len(tilt))
                                   + f" (tilt {DISTINCT_ANGLE_DEG:g} deg or more between "
                                   "poses)"))
    if len(in_sample) < 3:
        warnings.append(RunWarning("gyro_few_rotations", f"only {len(in_sample)} rotations "
                                   "between still poses: the 9 gyroscope parameters are barely "
                                   "determined; record more poses"))
    fit_rms = float(np.sqrt(np.mean(np.square(in_sample)))) if len(in_sample) else np.nan
    if fit_rms > 0 and cv.rms > OVERFIT_RATIO * fit_rms:
        # method.md §5: a large gap between the in-sample and held-out figures is overfitting.
        warnings.append(RunWarning(
            "gyro_overfitted",
            f"turns held out of the gyroscope fit are predicted {cv.rms / fit_rms:.1f} times "
            f"worse than the turns it saw ({cv.rms:.3g} against {fit_rms:.3g} deg RMS): the fit "
            "follows these turns more than the sensor; record more turns"))
    return warnings


def direction_error_cov(gravity: np.ndarray, gravity_cov: np.ndarray | FactoredCov,
                        R: np.ndarray) -> np.ndarray | FactoredCov:
    """Covariance (3K, 3K) of the residuals ``u_k - R_k^T u_(k-1)`` caused by errors in the
    measured gravity (noise of each block mean, and the accelerometer calibration's own
    uncertainty, shared by all blocks).

    Without it the standard errors of the gyroscope parameters come out about twice too small
    on synthetic sessions: consecutive residuals share a block, and the accelerometer's errors
    are common to all of them, so the residuals are not independent.

    The Jacobian ``Ju`` of the residuals with respect to the block means is block-bidiagonal,
    so a factored ``gravity_cov`` (:class:`FactoredCov` with block-diagonal ``B``) gives a
    factored result in ``O(K)``: ``(Ju U) C (Ju U)' + Ju B Ju'``, the last block-tridiagonal.
    A dense ``gravity_cov`` gives the dense product.
    """
    B = len(gravity)
    K = B - 1
    norm = np.linalg.norm(gravity, axis=1)
    u = gravity / norm[:, None]
    D = (np.eye(3)[None] - u[:, :, None] * u[:, None, :]) / norm[:, None, None]  # du/dg
    E = -np.einsum("kji,kjl->kil", R, D[:-1])  # -R_k^T du_(k-1)/dg
    if isinstance(gravity_cov, FactoredCov) and gravity_cov.upper is None:
        U = gravity_cov.U.reshape(B, 3, -1)
        Uj = (D[1:] @ U[1:] + E @ U[:-1]).reshape(3 * K, -1)
        N = gravity_cov.diag
        DN = D[1:] @ N[1:]  # Ju[k, k+1] N[k+1]
        diag = DN @ np.transpose(D[1:], (0, 2, 1)) + E @ N[:-1] @ np.transpose(E, (0, 2, 1))
        upper = DN[:-1] @ np.transpose(E[1:], (0, 2, 1))  # Ju[k,k+1] N[k+1] Ju[k+1,k+1]'
        return FactoredCov(Uj, gravity_cov.C, diag, upper)
    Ju = np.zeros((K, 3, B, 3))
    k = np.arange(K)
    Ju[k, :, k + 1, :] = D[1:]
    Ju[k, :, k, :] = E
    Ju = Ju.reshape(3 * K, 3 * B)
    return Ju @ np.asarray(gravity_cov) @ Ju.T
