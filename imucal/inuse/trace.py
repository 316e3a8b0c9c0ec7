"""A check's figures as they stood after each still moment (method.md §10): how the still-norm
error (M9) and the gyroscope's rate at rest (M10) built up over the recording, each with the
95 % interval the check gives it, so that a drift is seen where it starts. The last row of each
is the check's own figure (:func:`imucal.inuse.check.check`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from imucal.inuse.check import Z95, Check


@dataclass(frozen=True)
class Running:
    """One figure after each moment: ``t`` the moment's end (s), ``value`` and its 95 %
    interval ``low``-``high``, (B,) or (B, 3) per axis."""

    t: np.ndarray
    value: np.ndarray
    low: np.ndarray
    high: np.ndarray


def moment_norm_mg(check: Check, g: float) -> np.ndarray | None:
    """(B,) each moment's still-norm error (M9) with the stored calibration, mg; None without
    moments."""
    if check.acc_fit is None:
        return None
    return np.asarray(check.acc_fit.errors_before, float) / g * 1e3


def running_norm(check: Check, g: float) -> Running | None:
    """The still-norm RMS over the moments up to each one and its 95 % interval
    (``k E^2 / E_true^2 ~ chi^2_k``, as :func:`~imucal.inuse.check.rms_interval`), from the
    second moment on (the check judges no fewer); None with fewer than two."""
    e = moment_norm_mg(check, g)
    if e is None or len(e) < 2:
        return None
    k = np.arange(1, len(e) + 1)
    rms = np.sqrt(np.cumsum(e**2) / k)
    low = rms * np.sqrt(k / chi2.ppf(0.975, k))
    high = rms * np.sqrt(k / chi2.ppf(0.025, k))
    t = check.moments.times[:, 1]
    return Running(t[1:], rms[1:], low[1:], high[1:])


def running_rate(check: Check) -> Running | None:
    """The gyroscope's rate at rest left by the stored bias (M10, deg/s per axis) pooled over
    the moments up to each one by inverse variance, its standard error widened by their
    scatter where the reduced chi-square exceeds 1 (as
    :func:`~imucal.inuse.estimate.gyro_bias`), and the 95 % interval; None without a
    gyroscope's moments."""
    m = check.moments
    if m.rate is None or m.count == 0:
        return None
    r = np.degrees(m.rate)
    w = 1.0 / np.degrees(np.maximum(m.rate_se, 1e-12)) ** 2
    sw, swr, swr2 = (np.cumsum(x, axis=0) for x in (w, w * r, w * r**2))
    pooled = swr / sw
    k = np.arange(1, m.count + 1)[:, None]
    # sum w (r - pooled_k)^2 over the first k moments, from the running sums
    scatter = np.maximum(swr2 - 2 * pooled * swr + pooled**2 * sw, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        reduced = np.where(k > 1, scatter / np.maximum(k - 1, 1), 1.0)
    se = np.sqrt(np.maximum(reduced, 1.0)) / np.sqrt(sw)
    return Running(m.times[:, 1], pooled, pooled - Z95 * se, pooled + Z95 * se)
