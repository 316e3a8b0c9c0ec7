"""A low-range and a high-range accelerometer combined into one (method.md §11, M18): which is
which (stated ranges, or the one that clips), the low-range triad's clip levels, the blend
across a band below its limit, and the step between the two at the switch.

Everything here works on raw and calibrated samples already in the reference's frame: the
triads' own calibrations and their rotation come from :mod:`imucal.stages.triads`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from imucal.session import STANDARD_GRAVITY
from imucal.stages.saturation import axis_saturated_runs, saturated_mask

# The band of u (M18) across which the high-range triad takes over.
BAND = (0.80, 0.95)
# Two clip levels closer than this (relative) are one range: such a pair is not combined.
SAME_RANGE = 0.10


def g_per_unit(unit: str) -> float | None:
    """How many g one raw unit is (None for counts: no physical level without the scale)."""
    return {"g": 1.0, "m/s^2": 1.0 / STANDARD_GRAVITY}.get(unit)


def found_clip(raw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(3,) each axis's lowest and highest raw level where it sits flat for 5 samples or more
    (:func:`axis_saturated_runs`, §1's saturation), NaN where that side never clipped."""
    lo, hi = np.full(3, np.nan), np.full(3, np.nan)
    for j, runs in enumerate(axis_saturated_runs(raw)):
        if len(runs) == 0:
            continue
        levels = np.asarray(raw[runs[:, 0], j], float)
        top, bottom = levels.max(), levels.min()
        column_max, column_min = float(np.max(raw[:, j])), float(np.min(raw[:, j]))
        if top == column_max:
            hi[j] = top
        if bottom == column_min:
            lo[j] = bottom
    return lo, hi


@dataclass(frozen=True)
class ClipLevels:
    """The low-range triad's limits per raw axis (M18): ``lo``, ``hi`` (3,) in its raw unit,
    and how they are known ("found in the data", "stated", or both mixed)."""

    lo: np.ndarray
    hi: np.ndarray
    how: str

    def nearness(self, raw: np.ndarray) -> np.ndarray:
        """(N,) ``u = max_i |x_i - mid_i| / half_i`` (M18): 1 at the limit."""
        mid, half = (self.hi + self.lo) / 2, (self.hi - self.lo) / 2
        return np.max(np.abs(np.asarray(raw, float) - mid) / half, axis=1)

    @property
    def range_g_in(self) -> float:
        """The largest half-range, raw unit."""
        return float(np.max((self.hi - self.lo) / 2))

    def to_dict(self) -> dict:
        return {"lo": [float(v) for v in self.lo], "hi": [float(v) for v in self.hi],
                "how": self.how}


def clip_levels(raw: np.ndarray, unit: str, stated_g: float | None) -> ClipLevels | None:
    """The low-range triad's limits: found in its raw data; a side that never clipped takes the
    stated range (``stated_g``, in g) or, without one, the level found on another side (a
    part's range is symmetric about zero). None where nothing clipped and nothing is stated, or
    the raw unit has no level in g (counts) and the data give none."""
    lo, hi = found_clip(raw)
    per = g_per_unit(unit)
    found = np.r_[np.abs(lo[np.isfinite(lo)]), np.abs(hi[np.isfinite(hi)])]
    if stated_g is not None and per is not None:
        level = stated_g / per
    elif len(found):
        level = float(np.max(found))
    else:
        return None
    some = np.isfinite(lo).any() or np.isfinite(hi).any()
    every = np.isfinite(lo).all() and np.isfinite(hi).all()
    how = "found in the data" if every else (
        "found in the data, the rest " + ("stated" if stated_g is not None else "taken as "
                                          "symmetric") if some else "stated")
    return ClipLevels(lo=np.where(np.isfinite(lo), lo, -level),
                      hi=np.where(np.isfinite(hi), hi, level), how=how)


@dataclass(frozen=True)
class PairChoice:
    """Which of two accelerometer triads is the low-range one (0 or 1), and why; ``low`` None:
    not a low-range/high-range pair, ``why`` says why not."""

    low: int | None
    why: str


def choose_low(names: tuple[str, str], raws: tuple[np.ndarray, np.ndarray],
               units: tuple[str, str], stated: tuple[float | None, float | None]) -> PairChoice:
    """The low-range triad of a pair (M18): by the stated ranges where both are stated and
    differ; else the one whose axis clips (at the lower level in g, where both do, by more than
    :data:`SAME_RANGE`)."""
    if None not in stated:
        if abs(stated[0] - stated[1]) <= SAME_RANGE * max(stated):
            return PairChoice(None, f"{names[0]} and {names[1]} are stated with one range "
                                    f"({stated[0]:g} g): not a low-range and high-range pair")
        k = int(stated[1] < stated[0])
        return PairChoice(k, f"{names[k]} is stated with the lower range ({stated[k]:g} g "
                             f"against {stated[1 - k]:g} g)")
    levels = []
    for raw, unit in zip(raws, units):
        lo, hi = found_clip(raw)
        both = np.r_[np.abs(lo), np.abs(hi)]
        per = g_per_unit(unit)
        levels.append(np.nanmax(both) * per if np.isfinite(both).any() and per else np.nan)
    clips = [np.isfinite(v) for v in levels]
    if clips[0] and clips[1]:
        if abs(levels[0] - levels[1]) <= SAME_RANGE * max(levels):
            return PairChoice(None, f"{names[0]} and {names[1]} both clip near "
                                    f"{levels[0]:.3g} g: one range, not combined")
        k = int(levels[1] < levels[0])
    elif clips[0] or clips[1]:
        k = 0 if clips[0] else 1
    else:
        return PairChoice(None, f"neither {names[0]} nor {names[1]} clips and no range is stated "
                                "(--range NAME=G): not combined")
    return PairChoice(k, f"{names[k]} clips at {levels[k]:.3g} g, the other reads beyond it")


@dataclass(frozen=True)
class Step:
    """The step at the switch (M18): the mean of ``a_H - a_L`` over the samples inside the
    band, in mg, its standard error, and the samples it is the mean of."""

    vector_mg: np.ndarray  # (3,) reference frame
    std_mg: float  # standard error of its norm
    samples: int

    @property
    def mg(self) -> float:
        return float(np.linalg.norm(self.vector_mg))


def weights(u: np.ndarray, band: tuple[float, float] = BAND) -> np.ndarray:
    """(N,) ``w = s((u - u_1) / (u_2 - u_1))``, ``s(z) = 3 z^2 - 2 z^3`` on [0, 1] (M18)."""
    z = np.clip((np.asarray(u, float) - band[0]) / (band[1] - band[0]), 0.0, 1.0)
    return z * z * (3.0 - 2.0 * z)


def combine(a_low: np.ndarray, a_high: np.ndarray, u: np.ndarray, g: float,
            band: tuple[float, float] = BAND) -> tuple[np.ndarray, Step | None]:
    """``a_C = (1 - w) a_L + w a_H`` (M18) for the low-range triad's calibrated samples
    ``a_low`` and the high-range one's on the same clock ``a_high`` (NaN rows: no sample
    there, ``w = 0``), ``u`` the low-range triad's nearness to its limit; and the step at the
    switch (None without a sample in the band), ``g`` the output's |g| (mg = 1e3 / g)."""
    w = weights(u, band)
    have = np.all(np.isfinite(a_high), axis=1)
    w[~have] = 0.0
    out = a_low * (1.0 - w)[:, None]
    out[have] += a_high[have] * w[have, None]
    inside = have & (u >= band[0]) & (u <= band[1])
    n = int(inside.sum())
    step = None
    if n >= 2:
        d = (a_high[inside] - a_low[inside]) * (1e3 / g)
        mean = d.mean(axis=0)
        se = float(np.sqrt(np.sum(d.var(axis=0, ddof=1)) / n))
        step = Step(vector_mg=mean, std_mg=se, samples=n)
    return out, step


def clipped(raw: np.ndarray) -> np.ndarray:
    """(N,) the low-range triad's clipped samples (§1's saturation): left out of its fit."""
    return saturated_mask(np.asarray(raw))


def step_text(step: Step | None, low: str, high: str, noise_mg: float | None) -> str:
    """The step at the switch said, against the high-range triad's noise."""
    if step is None:
        return (f"combined accelerometer (acx, acy, acz): no sample of {low} came within "
                f"{BAND[0]:.0%}-{BAND[1]:.0%} of its range, so the step at the switch to {high} "
                "is not measured")
    ratio = "" if not noise_mg else (f", {step.mg / noise_mg:.2g} x {high}'s noise "
                                     f"({noise_mg:.3g} mg)")
    return (f"combined accelerometer (acx, acy, acz): {low} below {BAND[0]:.0%} of its range, "
            f"{high} above {BAND[1]:.0%}, blended between; the step at the switch is "
            f"{step.mg:.3g} mg (+- {step.std_mg:.2g}, {step.samples} samples in the band){ratio}")
