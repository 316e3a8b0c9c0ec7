"""Gyroscope calibration (method.md §4: M4, M5)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import minimize_scalar

from .errors import ImucalError
from .integrate import ordered_product_soa, padded_steps, rk4_steps
from .lm import FitReport, fit_tikhonov, sandwich_cov
from .models import GYRO_THETA0, SensorModel, gyro_T
from .quaternion import rotate_inverse, to_matrix


@dataclass(frozen=True)
class GyroSettings:
    """``bias``: ``"all"`` (every static block of the segment) or ``"first"`` (the thesis: the
    first block). ``optimise_bias`` adds the bias to the fit, its prior the static estimate.
    ``nominal_scale``: rad/s per raw unit for a gyroscope in counts (datasheet sensitivity);
    without it the scale is found from the data and "before" figures are not reported."""

    lam: float = 1e-4
    bias: str = "all"
    optimise_bias: bool = False
    nominal_scale: float | None = None


class Transitions:
    """The gyroscope samples of every motion between consecutive static blocks, laid out once.

    Transition k runs from the end of block k to the start of block k+1; its RK4 steps are
    padded to the longest transition (identity steps do not change the product), so every
    cost evaluation is a handful of vector operations over all transitions (M5).
    """

    def __init__(self, w_raw: np.ndarray, t: np.ndarray, block_times: np.ndarray):
        t_end_prev = block_times[:-1, 1]
        t_start_next = block_times[1:, 0]
        s = np.clip(np.searchsorted(t, t_end_prev, side="left") - 1, 0, len(t) - 1)
        e = np.clip(np.searchsorted(t, t_start_next, side="right"), 0, len(t) - 1)
        e = np.maximum(e, s)
        self.starts, self.ends = s, e
        self.n_steps = e - s
        i0, self.dt = padded_steps(t, s, e)
        # Components as separate contiguous (K, L) arrays: the hot loop is elementwise.
        comps = [np.ascontiguousarray(w_raw[:, i]) for i in range(3)]
        self.w0 = [c[i0] for c in comps]
        self.w1 = [c[i0 + 1] for c in comps]

    def __len__(self) -> int:
        return len(self.starts)

    def rotations(self, model: SensorModel) -> np.ndarray:
        """Quaternion of the body rotation over each transition under ``model`` (K, 4)."""
        return ordered_product_soa(rk4_steps(_apply(model, self.w0), _apply(model, self.w1),
                                             self.dt))

    def predict(self, model: SensorModel, u_prev: np.ndarray) -> np.ndarray:
        """M5: gravity of block k-1 carried into the body frame of block k, ``R_k^T u_(k-1)``."""
        return rotate_inverse(self.rotations(model), u_prev)


def _apply(model: SensorModel, w: list[np.ndarray]) -> tuple[np.ndarray, ...]:
    """M4 on component arrays: ``w_i = sum_j M_ij (w_raw_j - b_j)``."""
    M, b = model.matrix, model.b
    d = [w[j] - b[j] for j in range(3)]
    return tuple(M[i, 0] * d[0] + M[i, 1] * d[1] + M[i, 2] * d[2] for i in range(3))


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
    warnings: list[str] = field(default_factory=list)

    @property
    def angle_before(self) -> np.ndarray | None:
        return None if self.u_pred_before is None else angle_between(self.u_meas,
                                                                     self.u_pred_before)

    @property
    def angle_after(self) -> np.ndarray:
        return angle_between(self.u_meas, self.u_pred_after)


def angle_between(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Angle in degrees between rows of u and v (atan2 form: exact for small angles)."""
    c = np.linalg.norm(np.cross(u, v), axis=-1)
    d = np.einsum("ij,ij->i", u, v)
    return np.degrees(np.arctan2(c, d))


def static_bias(w_raw: np.ndarray, t: np.ndarray, block_times: np.ndarray, how: str
                ) -> tuple[np.ndarray, str]:
    """Gyroscope bias from the still periods (method.md §4)."""
    lo = np.searchsorted(t, block_times[:, 0], side="left")
    hi = np.searchsorted(t, block_times[:, 1], side="left")
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
    cs = np.vstack([np.zeros((1, 3)), np.cumsum(w_raw - w_raw[0], axis=0)])
    total = (cs[hi] - cs[lo]).sum(axis=0)
    n = int((hi - lo).sum())
    return total / n + w_raw[0], f"mean over all {len(lo)} static blocks ({n} samples)"


def _find_scale(tr: Transitions, bias: np.ndarray, u_prev: np.ndarray, u_meas: np.ndarray
                ) -> float:
    """Data-driven nominal scale for a gyroscope in raw counts: the isotropic scale s that
    best carries each gravity direction into the next, so no hand-set guess is needed.

    The angle between consecutive gravity directions is at most the angle turned, which is at
    most ``s`` times the integral of the raw rate's norm: their ratio brackets ``s`` from
    below. A log grid around that estimate, then a bounded 1-D refinement, finds the minimum
    of the M5 cost; with no usable rotation the grid spans eight decades.
    """

    def cost(log_s: float) -> float:
        m = SensorModel(T=np.eye(3), K=np.full(3, np.exp(log_s)), b=bias)
        r = u_meas - tr.predict(m, u_prev)
        return float(np.sum(r * r))

    turned = np.radians(angle_between(u_prev, u_meas))
    d = [0.5 * (w0 + w1) - b for w0, w1, b in zip(tr.w0, tr.w1, bias)]
    raw_turn = np.sum(np.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2) * tr.dt, axis=1)
    ok = (turned > np.radians(10.0)) & (raw_turn > 0)
    if ok.any():
        est = float(np.median(turned[ok] / raw_turn[ok]))
        grid = np.linspace(np.log(est / 2.0), np.log(est * 4.0), 25)
    else:
        grid = np.linspace(np.log(1e-7), np.log(10.0), 160)
    costs = np.array([cost(g) for g in grid])
    i = int(np.argmin(costs))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    res = minimize_scalar(cost, bounds=(lo, hi), method="bounded", options={"xatol": 1e-6})
    return float(np.exp(res.x))


def calibrate_gyroscope(w_raw: np.ndarray, t: np.ndarray, block_times: np.ndarray,
                        gravity: np.ndarray, gyro_unit: str,
                        settings: GyroSettings = GyroSettings(),
                        gravity_cov: np.ndarray | None = None) -> GyroFit:
    """Fit M4 so that integrating the calibrated rate (M5) turns each block's gravity
    direction into the next one's.

    ``block_times`` (B, 2) are the static blocks in seconds and ``gravity`` (B, 3) their mean
    calibrated accelerations, with ``gravity_cov`` (3B, 3B) their covariance when known (see
    :func:`direction_error_cov`).
    """
    if len(block_times) < 2:
        raise ImucalError(f"{len(block_times)} static block(s): the gyroscope needs at least two "
                          "still poses with a rotation between them", source="gyroscope",
                          field="static blocks")
    warnings: list[str] = []
    u = gravity / np.linalg.norm(gravity, axis=1, keepdims=True)
    u_prev, u_meas = u[:-1], u[1:]
    bias, bias_source = static_bias(w_raw, t, block_times, settings.bias)
    tr = Transitions(w_raw, t, block_times)

    if gyro_unit == "counts":
        if settings.nominal_scale:
            s0, how = float(settings.nominal_scale), "given sensitivity"
        else:
            s0, how = _find_scale(tr, bias, u_prev, u_meas), "1-D search on the data (counts)"
    else:
        s0, how = 1.0, "input in rad/s"
    have_nominal = gyro_unit != "counts" or bool(settings.nominal_scale)

    theta0 = GYRO_THETA0.copy()
    n_bias = 3 if settings.optimise_bias else 0
    if n_bias:
        theta0 = np.r_[theta0, np.zeros(3)]  # bias correction in nominal rad/s

    def model_of(theta: np.ndarray) -> SensorModel:
        b = bias + (theta[9:12] / s0 if n_bias else 0.0)
        return SensorModel(T=gyro_T(theta), K=theta[6:9] * s0, b=b)

    def res(theta: np.ndarray) -> np.ndarray:
        return (u_meas - tr.predict(model_of(theta), u_prev)).ravel()

    report = fit_tikhonov(res, None, theta0, theta0, settings.lam, start_name="prior")
    model = model_of(report.theta)
    cov = report.cov
    if gravity_cov is not None:
        R = to_matrix(tr.rotations(model))
        meat = direction_error_cov(gravity, gravity_cov, R)
        n, p = report.jac.shape
        # Each residual is the difference of two unit vectors: only its 2 components across
        # u_k carry error to first order, so a transition gives 2 degrees of freedom, not 3.
        s2 = max(report.data_cost - float(np.trace(meat)), 0.0) / max(2 * n // 3 - p, 1)
        cov, _ = sandwich_cov(report.jac, settings.lam, s2, meat)
    std = np.sqrt(np.clip(np.diag(cov), 0, None))
    std[6:9] *= s0
    if n_bias:
        std[9:12] /= s0

    before = None
    if have_nominal:
        raw_model = SensorModel(T=np.eye(3), K=np.full(3, s0), b=np.zeros(3))
        before = tr.predict(raw_model, u_prev)
    after = tr.predict(model, u_prev)
    angle = 2 * np.degrees(np.arccos(np.clip(np.abs(tr.rotations(model)[:, 0]), 0, 1)))

    if np.any(model.K <= 0):
        warnings.append("gyroscope fit reached a non-positive scale: the result is not physical")
    elif np.any(np.abs(report.theta[6:9] - 1) > 0.5):
        warnings.append(f"gyroscope scales {np.round(report.theta[6:9], 3).tolist()} (nominal "
                        "frame) are far from 1: check the gyroscope unit")
    if report.cost > report.cost_start * (1 + 1e-9):
        warnings.append("gyroscope fit ended with a higher cost than it started from")
    w_cal = _apply(model, tr.w0)
    per_step = np.sqrt(w_cal[0] ** 2 + w_cal[1] ** 2 + w_cal[2] ** 2) * tr.dt
    if per_step.size and per_step.max() > np.radians(20.0):
        warnings.append(f"rotations too fast for the gyroscope's sample rate: up to "
                        f"{np.degrees(per_step.max()):.0f} degrees between two samples; the "
                        "integration (M5) loses accuracy above about 20: turn more slowly")
    small = np.count_nonzero(angle < 10.0)
    if small:
        warnings.append(f"{small} of {len(angle)} rotations between still poses are under 10 "
                        "degrees and carry little information about the gyroscope")
    if len(u_meas) < 3:
        warnings.append(f"only {len(u_meas)} rotations between still poses: the 9 gyroscope "
                        "parameters are barely determined; record more poses")
    return GyroFit(model=model, std=std, bias_source=bias_source, nominal_scale=s0,
                   nominal_how=how, lam=settings.lam, report=report, u_prev=u_prev,
                   u_meas=u_meas, u_pred_before=before, u_pred_after=after,
                   t_transition=np.column_stack([t[tr.starts], t[tr.ends]]),
                   rotation_angle=np.radians(angle), warnings=warnings)


def direction_error_cov(gravity: np.ndarray, gravity_cov: np.ndarray, R: np.ndarray
                        ) -> np.ndarray:
    """Covariance (3K, 3K) of the residuals ``u_k - R_k^T u_(k-1)`` caused by errors in the
    measured gravity (noise of each block mean, and the accelerometer calibration's own
    uncertainty, shared by all blocks).

    Without it the standard errors of the gyroscope parameters come out about twice too small
    on synthetic sessions: consecutive residuals share a block, and the accelerometer's errors
    are common to all of them, so the residuals are not independent.
    """
    B = len(gravity)
    K = B - 1
    norm = np.linalg.norm(gravity, axis=1)
    u = gravity / norm[:, None]
    D = (np.eye(3)[None] - u[:, :, None] * u[:, None, :]) / norm[:, None, None]  # du/dg
    Ju = np.zeros((K, 3, B, 3))
    k = np.arange(K)
    Ju[k, :, k + 1, :] = D[1:]
    Ju[k, :, k, :] = -np.einsum("kji,kjl->kil", R, D[:-1])  # -R_k^T du_(k-1)/dg
    Ju = Ju.reshape(3 * K, 3 * B)
    return Ju @ gravity_cov @ Ju.T
