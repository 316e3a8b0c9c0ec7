"""Slow drifts within a segment: a bias that moves while the session is recorded (issue 27).

The grouping (method.md §2) looks for a *step*, one calibration before a block and another
after it; a bias that creeps (a sensor warming up) is no step, and a 20 mg ramp of the
accelerometer's bias over a session stayed one segment without a word, its blocks scattering
50-150 times beyond their own noise. Here each segment's still blocks are asked the question
the ramp answers, by an F-test of nested linear models:

- accelerometer: the M3 residuals of the block means (weighted as the grouping weighs them,
  :func:`imucal.stages.group.block_weights`), linearised at the segment's fit, against the
  same with a bias that changes linearly in time, ``b(t) = b + c (t - t_mid) / T`` (3 more
  parameters, ``c`` the change over the segment's span ``T``; method.md M7);
- gyroscope: each still block's mean rate (the bias, method.md §4), weighted by the inverse
  variance of the mean from its own scatter, against a line in time per axis.

``F = ((RSS_1 - RSS_2) / 3) / (RSS_2 / dof_2)``, F(3, dof_2) distributed when the bias is steady;
the noise's scale is taken from ``RSS_2`` as in the grouping (real block means scatter more
than white noise: that alone must not read as a drift). A drift is said when ``p < ALPHA``
and the change is large enough to matter (``ACC_MIN_MG``, ``GYRO_MIN_DEG``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from imucal.stages.accel import AccFit, jacobian, residuals
from imucal.stages.group import block_mean_variance, block_weights
from imucal.stages.gyro_transitions import sorted_position
from imucal.warning import RunWarning

ALPHA = 1e-3  # one test per sensor and segment: no multiple-testing correction to make
# A change of the accelerometer's bias this large over a segment (mg) is worth a word: a fifth
# of the verdict's caveat line (imucal.stages.verdict.ACC_CAVEAT_MG, 2 mg), against which one
# calibration of a changing sensor is off by up to half the change at either end.
ACC_MIN_MG = 0.4
# A gyroscope bias change that turns a 2-s turn by 0.1 deg (a good fit's held-out figure is
# 0.1-0.5 deg): 0.05 deg/s.
GYRO_MIN_DPS = 0.05
# What a drift warning ends with (the verdict gives it as its next step instead)
ADVICE = ("one calibration is fitted to a sensor that changed: let it warm up before recording, "
          "or record a shorter session")
# What a drift left after the temperature model ends with (method.md §8, §12): the temperature
# explains the rest, so warming up is not the whole answer.
ADVICE_IN_TEMPERATURE = ("one calibration in temperature is fitted to a sensor that changed in a "
                         "way its temperature does not explain: check that the temperature is "
                         "the sensor's own, or record a shorter session")


@dataclass(frozen=True)
class DriftTest:
    """The bias of one sensor in one segment: steady, or changing linearly in time."""

    sensor: str  # "accelerometer" or "gyroscope"
    change: np.ndarray  # (3,) the fitted change over the segment's span: mg, or deg/s
    f: float
    dof: tuple[int, int]
    p_value: float
    noise_ratio: float  # the blocks' scatter about a steady bias over what their noise predicts
    blocks: int
    # The model the change is beyond: None, a steady bias (M7); else its words, e.g. "the bias
    # of order 2 in temperature" (the residual after M16, method.md §8).
    beyond: str | None = None

    @property
    def size(self) -> float:
        return float(np.linalg.norm(self.change))

    @property
    def drifting(self) -> bool:
        least = ACC_MIN_MG if self.sensor == "accelerometer" else GYRO_MIN_DPS
        return bool(self.p_value < ALPHA and self.size > least)

    def warning(self, segment: int | None) -> RunWarning | None:
        """What the test measured, said when the bias drifts (None otherwise)."""
        if not self.drifting:
            return None
        unit = "mg" if self.sensor == "accelerometer" else "deg/s"
        code = "acc_bias_drift" if self.sensor == "accelerometer" else "gyro_bias_drift"
        if self.beyond is not None:
            return RunWarning(code, (
                f"the {self.sensor}'s bias moved during the recording beyond what its "
                f"temperature explains: about {self.size:.2g} {unit} over the recording that "
                f"{self.beyond} does not follow (a bias changing linearly in time as well "
                f"explains the {self.blocks} still blocks better: F {self.f:.3g}, p "
                f"{self.p_value:.2g}; they scatter {self.noise_ratio:.3g} times beyond their "
                f"own noise about {self.beyond}); {ADVICE_IN_TEMPERATURE}"), segment)
        return RunWarning(code, (
            f"the {self.sensor}'s bias moved during the recording: about {self.size:.2g} "
            f"{unit} from the first still pose to the last (a bias changing linearly in time "
            f"explains the {self.blocks} still blocks better than a steady one: F "
            f"{self.f:.3g}, p {self.p_value:.2g}; they scatter {self.noise_ratio:.3g} times "
            f"beyond their own noise about a steady bias); {ADVICE}"), segment)


def f_test(rss1: float, rss2: float, dof2: int) -> tuple[float, float]:
    # imported here, where a test runs: scipy.special costs ~0.1 s CPU to import
    from scipy.special import fdtrc

    if dof2 < 1 or not rss2 > 0:
        return float("nan"), float("nan")
    f = max(rss1 - rss2, 0.0) / 3 / (rss2 / dof2)
    return float(f), float(fdtrc(3, dof2, f))


def time_fraction(t_mid: np.ndarray) -> np.ndarray:
    span = float(t_mid.max() - t_mid.min())
    return (t_mid - t_mid.mean()) / (span if span > 0 else 1.0)


def accelerometer_drift(acc: np.ndarray, blocks: np.ndarray, means: np.ndarray,
                        t_mid: np.ndarray, fit: AccFit) -> DriftTest | None:
    """M7 for one segment's accelerometer: ``blocks`` (B, 2) its still blocks (sample
    ranges), ``means`` (B, 3) their raw means, ``t_mid`` (B,) their mid times, ``fit`` its
    calibration. None with fewer than 13 blocks (no degree of freedom left for the
    12-parameter model)."""
    B = len(blocks)
    if B < 13:
        return None
    m = fit.nominal.to_nominal(means)
    var = block_mean_variance(acc, blocks) / fit.nominal.scale ** 2
    theta = fit.theta_nominal
    w, scale = block_weights(m, var, theta)
    r = w * residuals(theta, m)
    J = w[:, None] * jacobian(theta, m)
    K = J[:, 6:9] * time_fraction(t_mid)[:, None]  # d r / d c: the bias's columns times the time
    rss1 = _rss(J, r)
    x, rss2 = lstsq(np.hstack([J, K]), r)
    f, p = f_test(rss1, rss2, B - 12)
    # x is the step from the fit, c its last three (nominal frame, |g| = 1): the change in mg
    return DriftTest("accelerometer", x[9:12] * 1e3, f, (3, B - 12), p,
                     float(scale * rss1 / max(B - 9, 1)), B)


def gyroscope_drift(w_raw, t, block_times: np.ndarray, rad_s_per_raw: np.ndarray
                    ) -> DriftTest | None:
    """The still blocks' mean rates against a line in time. ``rad_s_per_raw`` (3,) converts
    the raw unit (the fitted scale for counts, 1 for rad/s). ``w_raw`` and ``t`` are read by
    slices of rows, a block at a time."""
    times = np.asarray(block_times, float).reshape(-1, 2)
    ok, m, sw = block_rates(w_raw, t, times)
    B = len(m)
    if B < 4:
        return None
    tau = time_fraction(times[ok].mean(axis=1))
    rss1 = rss2 = 0.0
    change = np.empty(3)
    for i in range(3):
        y = m[:, i] * sw[:, i]
        A1 = sw[:, i:i + 1]
        A2 = np.column_stack([sw[:, i], sw[:, i] * tau])
        rss1 += _rss(A1, y)
        coef, r2 = lstsq(A2, y)
        rss2 += r2
        change[i] = coef[1]
    dof2 = 3 * B - 6
    f, p = f_test(rss1, rss2, dof2)
    dps = np.degrees(change * np.asarray(rad_s_per_raw, float))
    return DriftTest("gyroscope", dps, f, (3, dof2), p, float(rss1 / (3 * B - 3)), B)


def block_rates(w_raw, t, times: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The still blocks ``times`` (B, 2) of 3 samples or more (``ok``, (B,)): each one's mean
    rate (n, 3) and the inverse standard error of that mean per axis (n, 3), floored so that no
    block outweighs the rest. ``w_raw`` and ``t`` are read by slices of rows."""
    lo = sorted_position(t, times[:, 0], side="left")
    hi = np.maximum(sorted_position(t, times[:, 1], side="right"), lo)
    ok = (hi - lo) >= 3
    lo, hi = lo[ok], hi[ok]
    m = np.empty((len(lo), 3))
    v = np.empty((len(lo), 3))
    for k, (a, b) in enumerate(zip(lo, hi)):  # one step per block, numpy within
        x = np.asarray(w_raw[a:b], float)
        m[k] = x.mean(axis=0)
        v[k] = x.var(axis=0, ddof=1) / len(x)
    if len(m):
        med = np.median(v, axis=0)
        v = np.maximum(v, 0.01 * np.where(med > 0, med, 1.0))  # no block outweighs the rest
    return ok, m, 1.0 / np.sqrt(v)


def lstsq(A: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, float]:
    x = np.linalg.lstsq(A, y, rcond=None)[0]
    res = y - A @ x
    return x, float(res @ res)


def _rss(A: np.ndarray, y: np.ndarray) -> float:
    return lstsq(A, y)[1]
