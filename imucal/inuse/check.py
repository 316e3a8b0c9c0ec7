"""Does a stored calibration still hold in use? (method.md §10)

From the still moments of a recording of ordinary use: the accelerometer's still-norm error
(M9) against what the stored calibration leads one to expect, and the gyroscope's rate at rest
(M10) against zero (the stored bias), each with its 95 % interval; the verdict holds, drifted
(which parameters, by how much) or cannot tell (why). Pure computation: the calibration, its
stored figures and the session come in, a :class:`Check` goes out."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2

from imucal.inuse.estimate import (
    MIN_ACC_MOMENTS,
    AccFit,
    Estimate,
    GyroBias,
    fit_acc,
    gyro_bias,
)
from imucal.inuse.limits import ACC_LIMIT_MG, GYRO_LIMIT_DEG_S
from imucal.inuse.moments import ModelRows, Moments, find_moments
from imucal.session import Session
from imucal.stages.apply import Calibration, SegmentModels

HOLDS, DRIFTED, CANNOT_TELL, NOT_CHECKED = "holds", "drifted", "cannot tell", "not checked"
EXIT_CODES = {HOLDS: 0, DRIFTED: 1, CANNOT_TELL: 2}
MIN_ACC_ORIENTATIONS = 3
MIN_GYRO_STILL_S = 3.0
Z95 = 1.959963984540054
DEFAULT_NORM_MG = 1.0  # S when the calibration stores no still-norm figure


@dataclass(frozen=True)
class Stored:
    """What the calibration file says besides its parameters: its held-out still-norm error
    (mg, §5) and the accelerometer's white noise density (calibrated unit per sqrt(Hz), A1),
    which at the recording's rate gives the noise per sample: ``sigma = N sqrt(rate)``."""

    static_norm_mg: float | None = None
    acc_noise_density: float | None = None


@dataclass(frozen=True)
class Part:
    """One sensor's judgement: its figure with a 95 % interval, the limit it was held to and
    what the stored calibration leads one to expect, and the parameters that moved."""

    sensor: str
    level: str  # holds, drifted, cannot tell, not checked
    reason: str
    figure: str  # what the value is, in words
    value: float | None
    low: float | None
    high: float | None
    limit: float | None
    unit: str
    expected: float | None = None
    per_axis: dict | None = None  # the gyroscope's rate at rest per axis, with intervals
    changes: tuple[Estimate, ...] = ()  # the parameters the moments moved (beyond 2 SE)

    def to_dict(self) -> dict:
        return {"sensor": self.sensor, "level": self.level, "reason": self.reason,
                "figure": self.figure, "value": self.value, "ci95": [self.low, self.high],
                "limit": self.limit, "expected": self.expected, "unit": self.unit,
                "per_axis": self.per_axis, "changes": [c.to_dict() for c in self.changes]}


@dataclass(frozen=True)
class Check:
    level: str  # holds, drifted, cannot tell
    reason: str
    parts: tuple[Part, ...]
    moments: Moments
    segment: int  # which of the calibration's segments was checked (from 1): the last
    acc_fit: AccFit | None
    gyro: GyroBias | None
    notes: tuple[str, ...] = field(default_factory=tuple)

    @property
    def exit_code(self) -> int:
        return EXIT_CODES[self.level]

    def to_dict(self) -> dict:
        m = self.moments
        return {"verdict": self.level, "exit_code": self.exit_code, "reason": self.reason,
                "parts": [p.to_dict() for p in self.parts], "segment": self.segment,
                "still_moments": {
                    "count": m.count, "orientations": m.orientations,
                    "seconds": float(m.durations.sum()) if m.count else 0.0,
                    "times": m.times.tolist(),
                    "detector": {"window": m.window, "min_len": m.min_len, "k": m.k,
                                 "threshold": _finite(m.threshold),
                                 "reference_level": _finite(m.level),
                                 "reference_from": m.level_from, "rejected": m.rejected}},
                "notes": list(self.notes)}


def _finite(x: float) -> float | None:
    """JSON has no NaN: a figure not computed is null."""
    return float(x) if np.isfinite(x) else None


def last_segment(cal: Calibration) -> tuple[SegmentModels, int, tuple[str, ...]]:
    """The segment that describes the device now: the last (a note when there are several)."""
    notes = ()
    if len(cal.segments) > 1:
        notes = (f"the calibration has {len(cal.segments)} segments: the last, the device's "
                 "latest state, is the one checked",)
    return cal.segments[-1], len(cal.segments), notes


def moments_of(cal: Calibration, stored: Stored, session: Session
               ) -> tuple[Moments, SegmentModels, int, tuple[str, ...]]:
    """The still moments of ``session`` under the calibration's last segment."""
    cal.check_units(session)
    seg, number, notes = last_segment(cal)
    acc_cal = ModelRows(session.acc, seg.acc)  # calibrated a slice at a time (M2, M4)
    gyro_cal = t_gyro = None
    if session.has_gyro and seg.gyro is not None:
        gyro_cal, t_gyro = ModelRows(session.gyro, seg.gyro), session.t_gyro
    sigma = None
    if stored.acc_noise_density is not None:
        sigma = stored.acc_noise_density * float(np.sqrt(session.acc_rate))
    moments = find_moments(session.acc, acc_cal, np.asarray(session.t_acc),
                           gyro_cal, t_gyro, cal.g, sigma, session.acc_rate)
    if sigma is None:
        notes += ("the calibration stores no noise figures: the detector's level came from "
                  "the quietest 1 % of the recording",)
    return moments, seg, number, notes


def check(cal: Calibration, stored: Stored, session: Session, *,
          acc_limit_mg: float = ACC_LIMIT_MG, gyro_limit_deg_s: float = GYRO_LIMIT_DEG_S
          ) -> Check:
    """Judge whether ``cal`` still holds on ``session``, a recording of ordinary use: the
    accelerometer drifted where its still-norm RMS is shown above ``max(acc_limit_mg, twice
    the expected)``, the gyroscope where an axis' rate at rest is shown beyond
    ``gyro_limit_deg_s`` (95 % intervals)."""
    moments, seg, number, notes = moments_of(cal, stored, session)
    g = cal.g
    norm_mg = stored.static_norm_mg
    if norm_mg is None:
        norm_mg = DEFAULT_NORM_MG
        notes += (f"the calibration stores no still-norm error: {DEFAULT_NORM_MG:g} mg assumed",)
    fit = fit_acc(seg.acc, moments, g, norm_mg * 1e-3 * g, cal.acc_unit_raw) \
        if moments.count else None
    acc = _acc_part(moments, fit, norm_mg, g, acc_limit_mg)
    gb = None
    if seg.gyro is None or not session.has_gyro:
        gyro = Part("gyroscope", NOT_CHECKED, "no gyroscope in the calibration or the "
                    "recording", "rate at rest", None, None, None, None, "deg/s")
    else:
        gb = gyro_bias(seg.gyro, moments, cal.gyro_unit_raw or "rad/s")
        gyro = _gyro_part(gb, gyro_limit_deg_s)
    parts = (acc, gyro)
    judged = [p for p in parts if p.level != NOT_CHECKED]
    drifted = [p for p in judged if p.level == DRIFTED]
    unsure = [p for p in judged if p.level == CANNOT_TELL]
    if drifted:
        level, reason = DRIFTED, "; ".join(f"{p.sensor}: {p.reason}" for p in drifted)
    elif unsure:
        level, reason = CANNOT_TELL, "; ".join(f"{p.sensor}: {p.reason}" for p in unsure)
    else:
        level, reason = HOLDS, "; ".join(f"{p.sensor}: {p.reason}" for p in judged)
    return Check(level=level, reason=reason, parts=parts, moments=moments, segment=number,
                 acc_fit=fit, gyro=gb, notes=notes)


def rms_interval(e: np.ndarray) -> tuple[float, float, float]:
    """The RMS of ``e`` and its 95 % interval (``B E^2 / E_true^2 ~ chi^2_B``)."""
    b = len(e)
    rms = float(np.sqrt(np.mean(e**2)))
    return rms, rms * float(np.sqrt(b / chi2.ppf(0.975, b))), \
        rms * float(np.sqrt(b / chi2.ppf(0.025, b)))


def _acc_part(m: Moments, fit: AccFit | None, norm_mg: float, g: float,
              floor_mg: float) -> Part:
    """M9's RMS with its interval, against max(2 mg, twice the expected)."""
    if m.count < 2 or fit is None:
        return Part("accelerometer", CANNOT_TELL, f"too few still moments ({m.count}; "
                    f"{MIN_ACC_MOMENTS} in {MIN_ACC_ORIENTATIONS} orientations needed)",
                    "still-norm error RMS", None, None, None, None, "mg")
    e = fit.errors_before / g * 1e3
    rms, lo, hi = rms_interval(e)
    expected = float(np.sqrt(norm_mg**2 + np.mean(m.norm_var) / g**2 * 1e6))
    limit = max(floor_mg, 2 * expected)
    common = dict(figure="still-norm error RMS over the moments (M9)", value=rms, low=lo,
                  high=hi, limit=limit, unit="mg", expected=expected)
    if lo > limit:
        moved = tuple(c for c in fit.estimates if abs(c.change) > 2 * c.std_error)
        which = ", ".join(f"{c.parameter} by {_fmt_change(c)}" for c in moved) or (
            f"not which parameter: {_untold(m, fit)}")
        return Part("accelerometer", DRIFTED, f"still-norm error {rms:.2f} mg (95 % {lo:.2f}-"
                    f"{hi:.2f}) above {limit:.2f} mg; {which}", changes=moved, **common)
    if m.count < MIN_ACC_MOMENTS or m.orientations < MIN_ACC_ORIENTATIONS:
        short = (f"too few still moments ({m.count} of {MIN_ACC_MOMENTS})"
                 if m.count < MIN_ACC_MOMENTS else
                 f"too few orientations ({m.orientations} of {MIN_ACC_ORIENTATIONS}, 15 deg apart)")
        return Part("accelerometer", CANNOT_TELL, f"{short}: still-norm error {rms:.2f} mg "
                    f"(95 % {lo:.2f}-{hi:.2f}) is not shown above {limit:.2f} mg", **common)
    return Part("accelerometer", HOLDS, f"still-norm error {rms:.2f} mg (95 % {lo:.2f}-"
                f"{hi:.2f}) within {limit:.2f} mg over {m.count} moments in {m.orientations} "
                "orientations", **common)


def _untold(m: Moments, fit: AccFit) -> str:
    """Why a drifted accelerometer's moved parameters cannot be named."""
    if m.count < MIN_ACC_MOMENTS:
        return f"{m.count} still moments, {MIN_ACC_MOMENTS} needed"
    if not fit.covered.any():
        return "no axis has moments at 0.3 g on both sides"
    if fit.choice == "none":
        return ("no change of bias or scale predicts the moments better than the stored "
                "calibration (held out): recalibrate")
    return "no parameter moved beyond twice its standard error"


def _fmt_change(c: Estimate) -> str:
    if c.parameter.startswith("b"):
        return f"{c.change:+.4g} {c.unit} (+-{c.std_error:.2g})"
    return f"{c.change / c.stored * 100:+.3f} % (+-{c.std_error / abs(c.stored) * 100:.2g})"


def _gyro_part(gb: GyroBias | None, limit: float) -> Part:
    """The rate at rest per axis with its interval; drifted where an interval lies wholly
    beyond ``limit`` (deg/s)."""
    if gb is None or gb.still_s < MIN_GYRO_STILL_S:
        got = 0.0 if gb is None else gb.still_s
        return Part("gyroscope", CANNOT_TELL, f"too few still moments ({got:.1f} s still in "
                    f"all, {MIN_GYRO_STILL_S:g} s needed)", "rate at rest", None, None, None,
                    limit, "deg/s")
    r, se = np.degrees(gb.rate), np.degrees(gb.rate_se)
    lo, hi = r - Z95 * se, r + Z95 * se
    per_axis = {a: {"value": float(r[i]), "ci95": [float(lo[i]), float(hi[i])],
                    "std_error": float(se[i])} for i, a in enumerate("xyz")}
    beyond = (lo > limit) | (hi < -limit)
    norm = float(np.linalg.norm(r))
    common = dict(figure="rate at rest left by the stored bias (M10), norm over the axes",
                  value=norm, low=None, high=None, limit=limit, unit="deg/s",
                  expected=0.0, per_axis=per_axis)
    shown = ", ".join(f"{a} {r[i]:+.3f} (95 % {lo[i]:+.3f} to {hi[i]:+.3f})"
                      for i, a in enumerate("xyz"))
    if beyond.any():
        moved = tuple(c for i, c in enumerate(gb.estimates) if beyond[i])
        which = ", ".join(f"{c.parameter} by {c.change:+.4g} {c.unit} (+-{c.std_error:.2g})"
                          for c in moved)
        return Part("gyroscope", DRIFTED, f"bias moved: rate at rest {shown} deg/s, beyond "
                    f"{limit:g} deg/s; {which}", changes=moved, **common)
    return Part("gyroscope", HOLDS, f"rate at rest {shown} deg/s, within "
                f"{limit:g} deg/s over {gb.still_s:.0f} s of still moments",
                **common)
