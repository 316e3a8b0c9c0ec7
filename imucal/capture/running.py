"""The running calibration of a live capture (method.md §13): the method's fits on what the
incremental detector keeps, never on the session file, so that a capture's memory does not
grow with the stream.

- the accelerometer (M2, M3 with the maximum-likelihood block means, the L-curve, the data-only
  standard errors and the held-out figure, §3, §5, §8) needs only each hold's mean, count and
  per-axis variance: the same code as the batch method's, on the kept holds;
- the gyroscope (M4, M5) integrates the turns between the latest consecutive holds, each kept
  in bounded rows (:mod:`imucal.capture.turns`), with the still bias from the sums of every
  hold (§4's "all");
- the verdict is the batch method's (:func:`imucal.stages.verdict.judge`) on these fits as one
  segment, without the guide's turn-rate check and the drift tests, which need the samples.

The units are the loader's rule: the one the column names give, else guessed from the held
means (the accelerometer) and the turns' rates (the gyroscope).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from imucal.capture.detector import StillDetector
from imucal.errors import ImucalError
from imucal.io.column_names import classify_name
from imucal.io.units import SCALED_UNITS, resolve_acc_unit, resolve_gyro_unit
from imucal.models import ACC_PARAM_NAMES, GYRO_PARAM_NAMES, acc_theta, gyro_theta
from imucal.session import STANDARD_GRAVITY
from imucal.settings import Settings

# The spec's still-norm figure can no longer pass when even the lower bound of the excess
# scatter of the block means, at this one-sided level (5 standard errors of a normal), is
# over its limit (method.md §13).
LOST_ALPHA = 2.9e-7


@dataclass(frozen=True)
class Retained:
    """A copy of what the detector keeps, for a fit in another thread."""

    means: np.ndarray  # (B, 3) raw means of the kept holds
    n: np.ndarray  # (B,) their samples
    var: np.ndarray  # (B, 3) their per-axis sample variances
    chain_times: np.ndarray  # (C, 2) first and last still sample of the latest holds, s
    chain_means: np.ndarray  # (C, 3)
    chain_var_mean: np.ndarray  # (C, 3) per-axis variance of each of those means
    turns: np.ndarray  # (M, 4) t, wx, wy, wz: the turns between them, in order
    gyro_bias: np.ndarray  # (3,) raw, the mean over every hold's samples
    gyro_bias_var: np.ndarray  # (3,) its variance
    still_samples: int
    holds: int
    acc_hint: str | None  # the unit the column names give
    gyro_hint: str | None
    has_gyro: bool


def retained(det: StillDetector, names: list[str], acc_cols: list[int],
             gyro_cols: list[int] | None) -> Retained:
    """What ``det`` keeps now, copied; ``names`` and the columns say the units named."""
    holds, chain = det.holds, list(det.chain)
    turns = list(det.turns)
    return Retained(
        means=np.array([h.mean for h in holds]).reshape(-1, 3),
        n=np.array([h.n for h in holds], dtype=float),
        var=np.array([h.var for h in holds]).reshape(-1, 3),
        chain_times=np.array([[h.start, h.end] for h in chain]).reshape(-1, 2),
        chain_means=np.array([h.mean for h in chain]).reshape(-1, 3),
        chain_var_mean=np.array([h.var / max(h.n, 1) for h in chain]).reshape(-1, 3),
        turns=np.vstack(turns) if turns else np.zeros((0, 4)),
        gyro_bias=det.gyro_bias(), gyro_bias_var=det.gyro_bias_var(),
        still_samples=det.g_n, holds=det.n_holds,
        acc_hint=_hint(names, acc_cols), gyro_hint=_hint(names, gyro_cols),
        has_gyro=gyro_cols is not None)


def _hint(names: list[str], cols: list[int] | None) -> str | None:
    if not cols:
        return None
    return classify_name(names[cols[0]], None).unit


@dataclass(frozen=True)
class RunningFit:
    """The running calibration: the fits, their verdict and the figures a spec reads."""

    acc: Any  # imucal.stages.accel.AccFit
    gyro: Any  # imucal.stages.gyro.GyroFit | None
    level: str  # the verdict's level
    has_gyro: bool
    row: dict[str, Any]  # a summary row's figures (imucal.fleet.summary), and what "lost" needs
    per_unit: float  # rad/s per raw gyroscope unit (NaN when not known)


def fit_retained(r: Retained) -> RunningFit:
    """M2-M5 on the kept holds and turns (see the module); ImucalError when they do not
    calibrate yet."""
    from imucal.numerics.directions import distinct_orientations
    from imucal.stages.accel import fit_points, mean_cov
    from imucal.stages.accel_cv import leave_one_block_out
    from imucal.stages.accel_points import BlockNoise
    from imucal.stages.gyro import calibrate_gyroscope
    from imucal.stages.verdict import SegmentFigures, judge

    settings = Settings()
    notes: list[str] = []
    means, var, chain_means = r.means, r.var, r.chain_means
    chain_var, hint = r.chain_var_mean, r.acc_hint
    if hint in SCALED_UNITS:  # mg: the loader converts it to g
        hint, k = SCALED_UNITS[hint]
        means, var, chain_means, chain_var = means * k, var * k * k, chain_means * k, \
            chain_var * k * k
    if len(means) < 9:
        raise ImucalError(f"{len(means)} holds", source="capture")
    acc_unit = resolve_acc_unit(means, "auto", hint, "capture", notes)
    g_in = STANDARD_GRAVITY if acc_unit == "m/s^2" else 1.0
    acc = fit_points(means, BlockNoise(n=r.n, var=var), len(means), lambda: means,
                     acc_unit=acc_unit, g_in=g_in, g_out=g_in, settings=settings.acc)
    cv = leave_one_block_out(acc, means)
    orientations = distinct_orientations(means - acc.model.b)
    gyro, gyro_unit, per_unit = None, None, float("nan")
    bias_sd = np.full(3, np.nan)
    if r.has_gyro and len(r.chain_times) >= 3 and len(r.turns):
        w, bias, bias_var = r.turns[:, 1:], r.gyro_bias, r.gyro_bias_var
        ghint, k = r.gyro_hint, 1.0
        if ghint in SCALED_UNITS:  # mdeg/s
            ghint, k = SCALED_UNITS[ghint]
        gyro_unit = resolve_gyro_unit(w * k, "auto", ghint, acc_unit, notes)
        if gyro_unit == "deg/s":
            k, gyro_unit = k * np.pi / 180.0, "rad/s"
        w, bias, bias_var = w * k, bias * k, bias_var * k * k
        gyro = calibrate_gyroscope(
            w, r.turns[:, 0], r.chain_times, acc.model.apply(chain_means), gyro_unit,
            settings.gyro, mean_cov(chain_means, chain_var, acc),
            bias=(bias, f"mean over {r.still_samples} still samples of {r.holds} holds "
                        "(live)"))
        per_unit = k * (gyro.nominal_scale if gyro_unit == "counts" else 1.0)
        bias_sd = np.sqrt(bias_var)
    level = judge([SegmentFigures(None, cv, gyro, orientations)], None, ()).level
    row: dict[str, Any] = {"acc_unit_raw": acc_unit, "gyro_unit_raw": gyro_unit}
    row |= {f"acc_{n}": v for n, v in zip(ACC_PARAM_NAMES, acc_theta(acc.model))}
    row |= {f"acc_std_{n}": v for n, v in zip(ACC_PARAM_NAMES, acc.std)}
    row["static_norm_rms_mg_cv"] = cv.rms_mg
    row["static_norm_floor_mg"] = excess_floor(acc) * 1e3
    if gyro is not None:
        row |= {f"gyro_{n}": v for n, v in zip(GYRO_PARAM_NAMES, gyro_theta(gyro.model))}
        row |= {f"gyro_{n}": v for n, v in zip(("b_x", "b_y", "b_z"), gyro.model.b)}
        row |= {f"gyro_std_{n}": v for n, v in zip(GYRO_PARAM_NAMES, gyro.std)}
        sd = bias_sd if len(gyro.std) <= 9 else np.hypot(bias_sd, gyro.std[9:12])
        row |= {f"gyro_std_{n}": v for n, v in zip(("b_x", "b_y", "b_z"), sd)}
        row["gravity_angle_rms_deg_cv"] = gyro.cv.rms
    return RunningFit(acc=acc, gyro=gyro, level=level, has_gyro=r.has_gyro, row=row,
                      per_unit=per_unit)


def excess_floor(acc) -> float:
    """A lower bound (one-sided, ``LOST_ALPHA``) of the scatter ``tau`` the block means share
    beyond white noise (M3's excess variance), in units of |g|: the part of the still-norm
    error that neither more poses nor longer holds remove. 0 when white noise explains the
    residuals at that level (method.md §13)."""
    from scipy.stats import chi2

    from imucal.stages.accel import _dof
    from imucal.stages.accel_points import residuals

    data, report = acc.points, acc.report
    if data is None or data.white_var is None:
        return 0.0
    r2 = residuals(report.theta, data.pts, data.target) ** 2
    v = data.white_var
    dof = _dof(report)
    if dof <= 0:
        return 0.0
    q = float(chi2.isf(LOST_ALPHA, dof))
    if np.sum(r2 / v) <= q:
        return 0.0
    lo, hi = 0.0, float(np.sum(r2) / q)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if np.sum(r2 / (v + mid)) > q:
            lo = mid
        else:
            hi = mid
    return float(np.sqrt(lo))


def rate_per_unit(r: Retained) -> float:
    """rad/s per raw gyroscope unit by the unit the names give or the turns' rates suggest
    (the loader's rule), for the live view's turn rate before a running fit; NaN for raw
    counts (their scale comes from the fit) or without a gyroscope."""
    if not r.has_gyro or not len(r.turns):
        return float("nan")
    hint, k = r.gyro_hint, 1.0
    if hint in SCALED_UNITS:
        hint, k = SCALED_UNITS[hint]
    acc_hint = r.acc_hint if r.acc_hint not in SCALED_UNITS else SCALED_UNITS[r.acc_hint][0]
    acc_unit = acc_hint
    if acc_unit is None:
        from imucal.io.units import guess_acc_unit

        acc_unit = guess_acc_unit(r.means)[0] or "g"
    unit = resolve_gyro_unit(r.turns[:, 1:] * k, "auto", hint, acc_unit, [])
    return {"rad/s": k, "deg/s": k * np.pi / 180.0}.get(unit, float("nan"))
