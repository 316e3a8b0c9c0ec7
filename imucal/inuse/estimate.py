"""What the still moments of use say about the stored calibration's parameters (method.md
§10): the gyroscope's bias from M10's rates at rest, the accelerometer's biases and scales by
M11 on the axes the moments cover, each pulled towards its stored value by a prior."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from imucal.inuse.moments import Moments
from imucal.models import SensorModel

# An axis' bias and scale are told apart only with moments on both sides of it (GGIR's rule).
COVERAGE_G = 0.3
# Fewer moments than this refresh no accelerometer parameter: two moments on either side of an
# axis fit its bias and scale exactly, with nothing left to tell a moment's error from drift.
MIN_ACC_MOMENTS = 6
# The priors' widths (method.md §10, M11): wide next to what minutes of moments determine.
PRIOR_ACC_BIAS_G = 0.05
PRIOR_ACC_SCALE = 0.02
PRIOR_GYRO_BIAS_DEG_S = 1.0
AXES = "xyz"


@dataclass(frozen=True)
class Estimate:
    """One parameter as stored and as the moments put it, in the calibration's raw units."""

    sensor: str  # "accelerometer" or "gyroscope"
    parameter: str  # "b_x", "s_y", ... (the calibration file's names)
    stored: float
    value: float
    std_error: float
    unit: str

    @property
    def change(self) -> float:
        return self.value - self.stored

    def to_dict(self) -> dict:
        return {"sensor": self.sensor, "parameter": self.parameter, "stored": self.stored,
                "value": self.value, "change": self.change, "std_error": self.std_error,
                "unit": self.unit}


@dataclass(frozen=True)
class GyroBias:
    """The rate at rest the stored calibration leaves (calibrated frame, rad/s), pooled over
    the moments (no prior: the check's figure), and the refreshed raw bias (with the prior)."""

    rate: np.ndarray  # (3,) rad/s
    rate_se: np.ndarray  # (3,) rad/s
    still_s: float  # seconds of moments behind it
    estimates: tuple[Estimate, ...]  # b_x, b_y, b_z refreshed (prior included)


def coverage(moments: Moments, g: float) -> np.ndarray:
    """(3,) bool: the axes along which some moment reads >= 0.3 g and some <= -0.3 g."""
    if moments.count == 0:
        return np.zeros(3, bool)
    u = moments.cal_mean / g
    return (u >= COVERAGE_G).any(axis=0) & (u <= -COVERAGE_G).any(axis=0)


def gyro_bias(model: SensorModel, moments: Moments, gyro_unit: str) -> GyroBias | None:
    """M10's rates pooled by inverse variance, per axis; the standard error widened by the
    moments' scatter about the pooled value where it exceeds their own (reduced chi-square >
    1). The refreshed raw bias: the same with the prior of PRIOR_GYRO_BIAS_DEG_S, carried
    through ``(T_g K_g)^-1`` (M4)."""
    if moments.rate is None or moments.count == 0:
        return None
    r, se = moments.rate, np.maximum(moments.rate_se, 1e-12)
    w = 1.0 / se**2
    pooled = (w * r).sum(axis=0) / w.sum(axis=0)
    widen = np.ones(3)
    if moments.count >= 2:
        chi2 = (w * (r - pooled) ** 2).sum(axis=0) / (moments.count - 1)
        widen = np.sqrt(np.maximum(chi2, 1.0))
    rate_se = widen / np.sqrt(w.sum(axis=0))
    w0 = 1.0 / np.radians(PRIOR_GYRO_BIAS_DEG_S) ** 2  # prior: the stored bias, i.e. rate 0
    post = (w * r).sum(axis=0) / (w.sum(axis=0) + w0)
    post_se = widen / np.sqrt(w.sum(axis=0) + w0)
    inv = np.linalg.inv(model.matrix)  # calibrated rate -> raw units (M4)
    delta = inv @ post
    cov = inv @ np.diag(post_se**2) @ inv.T
    est = tuple(Estimate("gyroscope", f"b_{a}", float(model.b[i]), float(model.b[i] + delta[i]),
                         float(np.sqrt(cov[i, i])), gyro_unit) for i, a in enumerate(AXES))
    return GyroBias(rate=pooled, rate_se=rate_se, still_s=float(moments.durations.sum()),
                    estimates=est)


@dataclass(frozen=True)
class AccFit:
    """M11's solution: the parameters refreshed, the axes covered, and the still-norm errors
    before and after (g); which set of parameters was refreshed and why (held out)."""

    estimates: tuple[Estimate, ...]
    covered: np.ndarray  # (3,) bool
    model: SensorModel  # the stored model with the refreshed parameters
    errors_before: np.ndarray  # (B,) M9 with the stored model
    errors_after: np.ndarray  # (B,) M9 with the refreshed one
    choice: str = "none"  # "none", "bias" or "bias and scale"
    held_out_mg: dict | None = None  # each choice's held-out still-norm RMS, mg
    reason: str = ""


def norm_errors(model: SensorModel, raw_mean: np.ndarray, g: float) -> np.ndarray:
    """M9 for each moment: ``|T K (m_k - b)| - |g|``."""
    return np.linalg.norm(model.apply(raw_mean), axis=1) - g


FOLDS = 10
CHOICES = ("none", "bias", "bias and scale")


def fit_acc(model: SensorModel, moments: Moments, g: float, stored_norm: float,
            acc_unit: str) -> AccFit:
    """M11 over the covered axes' biases, or their biases and scales, whichever predicts the
    still moments it did not see best (K-fold over the moments in time order, as §5 judges a
    calibration by what it did not fit); none when neither beats the stored calibration on
    them (a misalignment or a change of shape that biases and scales cannot follow would be
    fitted to the orientations visited and miss the others). None either without a covered
    axis or with fewer than MIN_ACC_MOMENTS moments. ``stored_norm`` is S, the stored held-out
    still-norm error in the calibrated unit."""
    covered = coverage(moments, g) & (moments.count >= MIN_ACC_MOMENTS)
    before = norm_errors(model, moments.raw_mean, g)
    axes = np.flatnonzero(covered)
    if len(axes) == 0:
        return AccFit((), covered, model, before, before, reason="no axis covered")
    sigma = np.sqrt(stored_norm**2 + moments.norm_var)
    mg = 1e3 / g
    folds = np.array_split(np.arange(moments.count), min(FOLDS, moments.count))
    held = {"none": float(np.sqrt(np.mean(before**2))) * mg}
    for choice in CHOICES[1:]:
        e = np.empty(moments.count)
        for test in folds:
            train = np.setdiff1d(np.arange(moments.count), test)
            x, _, build = _solve(model, moments, g, sigma, axes, choice == CHOICES[2], train)
            e[test] = norm_errors(build(x), moments.raw_mean[test], g)
        held[choice] = float(np.sqrt(np.mean(e**2))) * mg
    choice = min(CHOICES, key=lambda c: (held[c], CHOICES.index(c)))
    shown = ", ".join(f"{c} {v:.2f} mg" for c, v in held.items())
    reason = f"held-out still-norm RMS refreshing {shown}: {choice} refreshed"
    if choice == "none":
        return AccFit((), covered, model, before, before, choice, held, reason)
    scale = choice == CHOICES[2]
    x, cov, build = _solve(model, moments, g, sigma, axes, scale, np.arange(moments.count))
    se = np.sqrt(np.clip(np.diag(cov), 0, None))
    names = [f"b_{AXES[i]}" for i in axes] + ([f"s_{AXES[i]}" for i in axes] if scale else [])
    stored = np.r_[model.b[axes], model.K[axes] if scale else []]
    est = tuple(Estimate("accelerometer", n, float(s), float(v), float(e), acc_unit if
                         n.startswith("b") else "ratio")
                for n, s, v, e in zip(names, stored, x, se))
    new = build(x)
    return AccFit(est, covered, new, before, norm_errors(new, moments.raw_mean, g), choice,
                  held, reason)


def _solve(model: SensorModel, moments: Moments, g: float, sigma: np.ndarray, axes: np.ndarray,
           scale: bool, use: np.ndarray):
    """M11 on the moments ``use``: the solution, its covariance (scaled by the reduced
    chi-square where above 1) and the model it builds."""
    K0, b0 = np.asarray(model.K, float), np.asarray(model.b, float)
    n = len(axes)
    p = np.r_[PRIOR_ACC_BIAS_G * g / np.abs(K0[axes]),  # a bias's prior, raw units
              PRIOR_ACC_SCALE * np.abs(K0[axes]) if scale else []]
    x0 = np.r_[b0[axes], K0[axes] if scale else []]
    m = moments.raw_mean[use]
    w = 1.0 / sigma[use]

    def build(x: np.ndarray) -> SensorModel:
        K, b = K0.copy(), b0.copy()
        b[axes] = x[:n]
        if scale:
            K[axes] = x[n:]
        return SensorModel(T=model.T, K=K, b=b)

    def residuals(x: np.ndarray) -> np.ndarray:  # M11
        return np.r_[norm_errors(build(x), m, g) * w, (x - x0) / p]

    sol = least_squares(residuals, x0, x_scale=p, method="trf")
    dof = len(use) - len(x0)
    chi2 = float(np.sum(sol.fun[:len(use)] ** 2) / dof) if dof > 0 else 1.0
    cov = np.linalg.pinv(sol.jac.T @ sol.jac) * max(chi2, 1.0)
    return sol.x, cov, build
