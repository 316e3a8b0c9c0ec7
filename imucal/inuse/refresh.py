"""Refresh a stored calibration from everyday use (method.md §10, M11): only what the still
moments determine changes -- the gyroscope's bias (M10, from 3 s of moments or more), the
accelerometer's bias and scale on each axis the moments cover at 0.3 g on both sides -- each
pulled towards its stored value by a prior; every other parameter stays exactly as stored."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from imucal.inuse.check import MIN_GYRO_STILL_S, Check, Stored, check
from imucal.inuse.estimate import AXES, COVERAGE_G, MIN_ACC_MOMENTS, Estimate
from imucal.models import SensorModel
from imucal.session import Session
from imucal.stages.apply import Calibration


@dataclass(frozen=True)
class Refresh:
    """The refreshed models of the checked segment, what changed and what was kept and why."""

    check: Check
    acc: SensorModel
    gyro: SensorModel | None
    changed: tuple[Estimate, ...]
    kept: tuple[str, ...]  # the parameters left as stored, with the reason, one line each
    norm_before_mg: float | None  # M9's RMS over the moments, stored and refreshed model
    norm_after_mg: float | None

    @property
    def determined(self) -> bool:
        return bool(self.changed)

    def to_dict(self) -> dict:
        return {"changed": [c.to_dict() for c in self.changed], "kept": list(self.kept),
                "still_norm_rms_mg": {"stored": self.norm_before_mg,
                                      "refreshed": self.norm_after_mg},
                "accelerometer_choice": None if self.check.acc_fit is None else {
                    "refreshed": self.check.acc_fit.choice,
                    "held_out_still_norm_rms_mg": self.check.acc_fit.held_out_mg,
                    "reason": self.check.acc_fit.reason},
                "still_moments": self.check.moments.count,
                "still_seconds": float(self.check.moments.durations.sum())
                if self.check.moments.count else 0.0,
                "check": {"verdict": self.check.level, "reason": self.check.reason}}


def refresh(cal: Calibration, stored: Stored, session: Session) -> Refresh:
    """M11 on ``session``'s still moments under ``cal``'s last segment."""
    c = check(cal, stored, session)
    seg = cal.segments[-1]
    changed: list[Estimate] = []
    kept: list[str] = []
    acc = seg.acc
    fit = c.acc_fit
    covered = np.zeros(3, bool) if fit is None else fit.covered
    if fit is not None and fit.estimates:
        acc = fit.model
        changed += fit.estimates
    if fit is not None and fit.choice == "none" and fit.held_out_mg is not None:
        kept.append(f"accelerometer biases and scales: {fit.reason}")
    elif fit is not None and fit.choice == "bias":
        kept.append(f"accelerometer scales: {fit.reason}")
    if c.moments.count < MIN_ACC_MOMENTS:
        kept.append(f"accelerometer biases and scales: {c.moments.count} still moments, "
                    f"{MIN_ACC_MOMENTS} needed")
    else:
        for i in np.flatnonzero(~covered):
            kept.append(f"accelerometer b_{AXES[i]}, s_{AXES[i]}: no moments at {COVERAGE_G:g} g "
                        f"on both sides of {AXES[i]}")
    kept.append("accelerometer misalignments: not refreshed from everyday use")
    gyro = seg.gyro
    if gyro is not None:
        gb = c.gyro
        if gb is not None and gb.still_s >= MIN_GYRO_STILL_S:
            gyro = dataclasses.replace(gyro, b=np.array([e.value for e in gb.estimates]))
            changed += gb.estimates
        else:
            got = 0.0 if gb is None else gb.still_s
            kept.append(f"gyroscope bias: {got:.1f} s of still moments, "
                        f"{MIN_GYRO_STILL_S:g} s needed")
        kept.append("gyroscope misalignments and scales: not refreshed from everyday use")
    before = after = None
    if fit is not None and len(fit.errors_before):
        before = float(np.sqrt(np.mean(fit.errors_before**2)) / cal.g * 1e3)
        after = float(np.sqrt(np.mean(fit.errors_after**2)) / cal.g * 1e3)
    return Refresh(check=c, acc=acc, gyro=gyro, changed=tuple(changed), kept=tuple(kept),
                   norm_before_mg=before, norm_after_mg=after)
