"""The run judged with its temperature model in force (method.md §8, §12): where ``calibrate
--temperature`` fitted a bias in temperature, ``apply`` calibrates each sample with it, so the
verdict's figures and the drift test (M7) are those of that model, not of the constant fit.

- the still-norm error of the accelerometer with M16 (and its scales' slope where fitted), in
  sample and held out: each still block predicted by M17 refitted without it, at its own
  temperature held inside the other blocks' span (the model is never extrapolated), evaluated
  through the model's own equation (:meth:`BiasPolynomial.calibrated`, what apply runs);
- M7 asked of what the temperature model leaves: does a bias changing linearly in time explain
  the blocks better than the polynomial in temperature alone? A drift the temperature explains
  is then no drift; what it does not explain still is, and is said so.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from imucal.models import SensorModel, acc_theta
from imucal.stages.drift import DriftTest, block_rates, f_test, lstsq, time_fraction
from imucal.stages.temperature import (
    BiasPolynomial,
    _inside_others,
    _norm_jacobian,
    fit_accel_bias_polynomial,
)


def _system(fit: BiasPolynomial, means: np.ndarray, models: list[SensorModel], g: float
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """M17 at the constant fit, as :func:`fit_accel_bias_polynomial` builds it, for the fit's
    blocks (``means``, ``models``: theirs): the norm residuals ``r`` (n,), their Jacobian
    (n, 9), and the temperatures on [-1, 1] about ``fit.t0``."""
    params = np.array([acc_theta(m) for m in models])
    r = np.array([np.linalg.norm(m.apply(x[None])[0]) for m, x in zip(models, means)]) - g
    return r, _norm_jacobian(means, params), (fit.temps - fit.t0) / max(fit.span_c / 2, 1e-6)


def _design(fit: BiasPolynomial, jac: np.ndarray, x: np.ndarray) -> np.ndarray:
    """M17's columns for the fit's order (and scale slope where it has one), without the
    legs' step: apply models no hysteresis."""
    poly = [jac[:, 6:9] * x[:, None] ** j for j in range(1, fit.order + 1)]
    scale = [jac[:, 3:6] * x[:, None]] if fit.scale_slope is not None else []
    return np.hstack([jac, *poly, *scale])


def _norm_error_mg(a: np.ndarray, g: float) -> np.ndarray:
    return (np.linalg.norm(a, axis=1) / g - 1.0) * 1e3


def accel_figures(fit: BiasPolynomial, temps: np.ndarray, means: np.ndarray,
                  models: list[SensorModel], g: float, legs: np.ndarray | None
                  ) -> tuple[BiasPolynomial, float]:
    """``fit`` with its still-norm errors (mg) in sample (``after_mg``) and held out
    (``held_out_mg``) over its blocks ``fit.used``; and the held-out over in-sample ratio a
    well-posed fit of its size shows anyway (``B / (B - q)``, q its unknowns), for the
    overfitting test. ``temps``, ``means``, ``models``, ``legs``: what ``fit`` was fitted to
    (:func:`fit_accel_bias_polynomial`, every block of the run). Held out means the whole fit
    made again without the block, its order and scale slope chosen by its own
    cross-validation (a block never helps choose the model that predicts it), and evaluated at
    the block's temperature through :meth:`BiasPolynomial.calibrated` (apply's equation).
    As in the order's cross-validation, a block outside the other blocks' span (an end of a
    ramp) is not scored (NaN): the fit without it would be extrapolated to it, which the model
    never is (held at its end value, it would measure that clamp, not the model)."""
    n = len(temps)
    held = np.full(len(fit.used), np.nan)
    scored = _inside_others(fit.temps)
    for i, k in enumerate(fit.used):  # one small fit per block (20-100 of them, ~5 ms each)
        if not scored[i]:
            continue
        keep = np.arange(n) != k
        other = fit_accel_bias_polynomial(temps[keep], means[keep],
                                          [m for m, x in zip(models, keep) if x], g,
                                          None if legs is None else legs[keep])
        if other is not None:
            held[i] = _norm_error_mg(other.calibrated(means[k:k + 1], temps[k:k + 1]), g)[0]
    after = _norm_error_mg(fit.calibrated(means[fit.used], fit.temps), g)
    q = 9 + 3 * fit.order + 3 * (fit.scale_slope is not None)
    return (replace(fit, after_mg=after, held_out_mg=held),
            len(fit.used) / max(len(fit.used) - q, 1e-9))


def _untracked(tau: np.ndarray, x: np.ndarray, order: int) -> float:
    """How far the time ``tau`` (over the span, -1/2 to 1/2) moves from the first block to the
    last where the polynomial in temperature cannot follow it: the range of its part orthogonal
    to ``1, x, .., x^order``. 1 for order 0 (M7's change over the segment); near 0 on a
    steady ramp, where time and temperature are one and a change in time is the temperature's
    to explain: the size said is the change the temperature model leaves."""
    v = np.vander(x, order + 1, increasing=True)
    return float(np.ptp(tau - v @ np.linalg.lstsq(v, tau, rcond=None)[0]))


def _words(fit: BiasPolynomial) -> str:
    slope = " and its scales' slope" if fit.scale_slope is not None else ""
    return f"the bias of order {fit.order} in temperature{slope}"


def accel_drift(fit: BiasPolynomial, means: np.ndarray, models: list[SensorModel], g: float,
                t_mid: np.ndarray, mean_var: np.ndarray) -> DriftTest | None:
    """M7 on what M17 leaves: the blocks' norm residuals fitted by the temperature model with
    and without a bias changing linearly in time as well (three more columns, ``d|u_k|/db``
    times the block's time over the span), the F-test of the two. ``t_mid`` (n,) the blocks'
    mid times, ``mean_var`` (n, 3) the raw variance of each block's mean (its noise). None
    without 3 blocks to spare."""
    r, jac, x = _system(fit, means, models, g)
    a = _design(fit, jac, x)
    n = len(r)
    dof2 = n - a.shape[1] - 3
    if dof2 < 3:
        return None
    sol1, rss1 = lstsq(a, -r)
    tau = time_fraction(t_mid)
    sol2, rss2 = lstsq(np.hstack([a, jac[:, 6:9] * tau[:, None]]), -r)
    f, p = f_test(rss1, rss2, dof2)
    # the raw bias's change as the output sees it, over the time temperature does not track
    change = fit.model.matrix @ sol2[-3:] / g * 1e3 * _untracked(tau, x, fit.order)
    # Each block's norm noise: d|u_k|/dm_k = -d|u_k|/db, through the variance of the mean.
    noise = np.sum(jac[:, 6:9] ** 2 * mean_var, axis=1)
    res = -r - a @ sol1
    ratio = float(np.sum(res**2 / np.maximum(noise, 1e-300)) / max(n - a.shape[1], 1))
    return DriftTest("accelerometer", change, f, (3, dof2), p, ratio, n, beyond=_words(fit))


def gyro_drift(fit: BiasPolynomial, w_raw, t, block_times: np.ndarray,
               rad_s_per_raw: np.ndarray) -> DriftTest | None:
    """M7 on what M16 leaves for the gyroscope: each still block's mean rate (``fit.used``'s
    blocks, ``block_times`` all the run's) against the polynomial in temperature of the fit's
    order, with and without a line in time per axis, weighted as
    :func:`imucal.stages.drift.gyroscope_drift` weighs them. None without 3 blocks to spare."""
    times = np.asarray(block_times, float)[fit.used]
    ok, m, sw = block_rates(w_raw, t, times)
    p, b = fit.order, len(m)
    dof2 = 3 * (b - p - 2)
    if b < p + 5:
        return None
    x = (fit.temps[ok] - fit.t0) / max(fit.span_c / 2, 1e-6)
    v = np.vander(x, p + 1, increasing=True)
    tau = time_fraction(times[ok].mean(axis=1))
    rss1 = rss2 = 0.0
    change = np.empty(3)
    for i in range(3):
        y = m[:, i] * sw[:, i]
        a1 = v * sw[:, i:i + 1]
        rss1 += lstsq(a1, y)[1]
        coef, r2 = lstsq(np.hstack([a1, (sw[:, i] * tau)[:, None]]), y)
        rss2 += r2
        change[i] = coef[-1]
    f, pv = f_test(rss1, rss2, dof2)
    dps = np.degrees(change * np.asarray(rad_s_per_raw, float)) * _untracked(tau, x, p)
    return DriftTest("gyroscope", dps, f, (3, dof2), pv, float(rss1 / (3 * (b - p - 1))), b,
                     beyond=_words(fit))


def explained_note(sensor: str, steady: DriftTest, after: DriftTest) -> str:
    """What the temperature did to a drift M7 found with a steady bias (method.md §8)."""
    unit = "mg" if sensor == "accelerometer" else "deg/s"
    head = (f"{sensor}: with a steady bias it moved about {steady.size:.2g} {unit} over the "
            f"recording (M7: F {steady.f:.3g}, p {steady.p_value:.2g}); ")
    if after.drifting:
        return head + (f"{after.beyond} leaves {after.size:.2g} {unit} of it unexplained (F "
                       f"{after.f:.3g}, p {after.p_value:.2g}): warned")
    return head + (f"{after.beyond} explains it (a drift in time beyond it: F {after.f:.3g}, "
                   f"p {after.p_value:.2g}): no drift warned")
