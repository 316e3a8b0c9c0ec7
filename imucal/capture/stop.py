"""When a capture has enough: the run is judged good and every accelerometer and gyroscope
parameter's standard error is under its target (method.md §13).

With a spec (the batch's limits file, checked by the caller's ``judge``), enough is also
"within its limits", and a calibration known to the targets but out of a limit can no longer
pass: the capture stops there, failed.

The targets are in the units a user reads: misalignment in mrad, scale factor relative to
itself in %, accelerometer bias in mg (the raw bias's error times the scale, over |g|). The
presets were measured on synthetic sessions at the default noise (3 mg, 3 mrad/s; seeds 3-5,
poses of 3 s): "quick" is met at 12-18 poses, "default" at 16-20, "factory" at 22-34.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from imucal.errors import ImucalError
from imucal.models import ACC_PARAM_NAMES, GYRO_PARAM_NAMES
from imucal.result import Result
from imucal.stages.verdict import GOOD


@dataclass(frozen=True)
class Targets:
    misalignment_mrad: float
    scale_pct: float
    acc_bias_mg: float

    def text(self) -> str:
        return (f"misalignment {self.misalignment_mrad:g} mrad, scale {self.scale_pct:g} %, "
                f"accelerometer bias {self.acc_bias_mg:g} mg")


PRESETS = {"quick": Targets(1.0, 0.1, 1.0), "default": Targets(0.5, 0.05, 0.5),
           "factory": Targets(0.25, 0.025, 0.25)}


def targets(name: str) -> Targets:
    try:
        return PRESETS[name]
    except KeyError:
        raise ImucalError(f"unknown target {name!r}; expected one of {', '.join(PRESETS)}",
                          source="--target") from None


@dataclass(frozen=True)
class Progress:
    """How far a calibration of the data so far is from the targets."""

    level: str  # the verdict's level ("" when the run gave none)
    worst: str  # the parameter furthest from its target ("segment 1 accelerometer s_x")
    ratio: float  # its standard error over its target (<= 1: every target met)
    met: bool  # the verdict is good, every ratio <= 1 and no limit of a spec broken
    firm: bool = False  # every ratio <= 1: the parameters are known to the targets
    broken: tuple[str, ...] = ()  # the limits of a spec (--spec) the calibration breaks

    @property
    def failed(self) -> bool:
        """Known to the targets and out of the spec's limits: it can no longer pass."""
        return self.firm and bool(self.broken)

    def text(self) -> str:
        spec = f"; out of the spec: {', '.join(self.broken)}" if self.broken else ""
        return (f"{self.level or 'no verdict'}; worst {self.worst} at "
                f"{self.ratio:.2f} x its target{spec}")


Judge = Callable[[Result], "list[str]"]  # the limits of a spec a result breaks


def progress(result: Result, goal: Targets, judge: Judge | None = None) -> Progress:
    """The ratios of each standard error to its target, over every segment's fits, and the
    limits ``judge`` (a spec's check, given by the caller) finds broken."""
    ratios: list[tuple[float, str]] = []
    mis, scale = goal.misalignment_mrad * 1e-3, goal.scale_pct * 1e-2
    for seg in result.segments:
        where = f"segment {seg.number}" if len(result.segments) > 1 else ""
        fit = seg.acc
        k = np.abs(fit.model.K)
        r = np.r_[fit.std[:3] / mis, fit.std[3:6] / k / scale,
                  fit.std[6:9] * k / abs(fit.g_out) / (goal.acc_bias_mg * 1e-3)]
        ratios += [(float(x), f"{where} accelerometer {n}".strip())
                   for x, n in zip(r, ACC_PARAM_NAMES)]
        if seg.gyro is not None:
            g = seg.gyro
            kg = np.abs(g.model.K)
            r = np.r_[g.std[:6] / mis, g.std[6:9] / kg / scale]
            ratios += [(float(x), f"{where} gyroscope {n}".strip())
                       for x, n in zip(r, GYRO_PARAM_NAMES)]
    level = result.verdict.level if result.verdict is not None else ""
    if not ratios:
        return Progress(level, "every parameter (no fit)", np.inf, False)
    ratio, worst = max(ratios, key=lambda p: p[0] if np.isfinite(p[0]) else np.inf)
    # A session with a gyroscope needs its fit in every segment before it can be enough.
    fitted = not result.session.has_gyro or all(s.gyro is not None for s in result.segments)
    firm = fitted and bool(ratio <= 1.0)
    broken = tuple(judge(result)) if judge is not None else ()
    return Progress(level, worst, ratio, level == GOOD and firm and not broken, firm, broken)
