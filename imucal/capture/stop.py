"""When a capture has enough: the run is judged good and every accelerometer and gyroscope
parameter's standard error is under its target (method.md §13).

With a spec (the batch's limits file, :mod:`imucal.fleet.spec`, as a :class:`SpecCheck`),
enough is also "within its limits"; and a capture whose running calibration can no longer be
within them stops there, failed (:func:`lost_limits`): a parameter beyond its limit by more
than ``LOST_Z`` of its standard errors, or a still-norm figure whose floor (the scatter no more
data removes) is over its limit.

The targets are in the units a user reads: misalignment in mrad, scale factor relative to
itself in %, accelerometer bias in mg (the raw bias's error times the scale, over |g|). The
presets were measured on synthetic sessions at the default noise (3 mg, 3 mrad/s; seeds 3-5,
poses of 3 s): "quick" is met at 12-18 poses, "default" at 16-20, "factory" at 22-34.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from imucal.errors import ImucalError
from imucal.models import ACC_PARAM_NAMES, GYRO_PARAM_NAMES
from imucal.stages.verdict import GOOD

if TYPE_CHECKING:
    from imucal.capture.running import RunningFit
    from imucal.result import Result


@dataclass(frozen=True)
class SpecCheck:
    """A spec (the batch's limits file, :mod:`imucal.fleet.spec`) as the capture uses it; the
    caller, which may import the fleet's modules, makes it (imucal.cli.capture)."""

    limits: dict[str, float]  # limit name -> value, in the spec's units
    broken: Callable[[dict], list[str]]  # the limits a summary row breaks (the spec's check)
    row_of: Callable[[Result], dict]  # a result's summary row (imucal.fleet.summary)


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
    lost: tuple[str, ...] = ()  # those it can no longer meet (lost_limits)

    @property
    def failed(self) -> bool:
        """Out of a spec's limits for good: it can no longer pass."""
        return bool(self.lost)

    def text(self) -> str:
        spec = ""
        if self.lost:
            spec = f"; can no longer meet the spec: {', '.join(self.lost)}"
        elif self.broken:
            spec = f"; out of the spec: {', '.join(self.broken)}"
        return (f"{self.level or 'no verdict'}; worst {self.worst} at "
                f"{self.ratio:.2f} x its target{spec}")


def progress(result: Result, goal: Targets, spec: SpecCheck | None = None) -> Progress:
    """The ratios of each standard error to its target, over every segment's fits, and the
    limits of ``spec`` the result breaks (as ``imucal calibrate --spec`` judges them)."""
    several = len(result.segments) > 1
    fits = [(f"segment {seg.number}" if several else "", seg.acc, seg.gyro)
            for seg in result.segments]
    # A session with a gyroscope needs its fit in every segment before it can be enough.
    fitted = not result.session.has_gyro or all(s.gyro is not None for s in result.segments)
    level = result.verdict.level if result.verdict is not None else ""
    broken = tuple(spec.broken(spec.row_of(result))) if spec is not None else ()
    return _progress(level, fits, fitted, goal, broken, ())


def running_progress(fit: RunningFit, goal: Targets, spec: SpecCheck | None = None
                     ) -> Progress:
    """:func:`progress` of a running calibration (imucal.capture.running), with the limits it
    can no longer meet."""
    broken = lost = ()
    if spec is not None:
        broken = tuple(spec.broken(fit.row))
        lost = tuple(lost_limits(spec.limits, fit.row))
    fitted = not fit.has_gyro or fit.gyro is not None
    return _progress(fit.level, [("", fit.acc, fit.gyro)], fitted, goal, broken, lost)


def _progress(level: str, fits: list, fitted: bool, goal: Targets, broken: tuple[str, ...],
              lost: tuple[str, ...]) -> Progress:
    ratios: list[tuple[float, str]] = []
    mis, scale = goal.misalignment_mrad * 1e-3, goal.scale_pct * 1e-2
    for where, fit, g in fits:
        k = np.abs(fit.model.K)
        r = np.r_[fit.std[:3] / mis, fit.std[3:6] / k / scale,
                  fit.std[6:9] * k / abs(fit.g_out) / (goal.acc_bias_mg * 1e-3)]
        ratios += [(float(x), f"{where} accelerometer {n}".strip())
                   for x, n in zip(r, ACC_PARAM_NAMES)]
        if g is not None:
            kg = np.abs(g.model.K)
            r = np.r_[g.std[:6] / mis, g.std[6:9] / kg / scale]
            ratios += [(float(x), f"{where} gyroscope {n}".strip())
                       for x, n in zip(r, GYRO_PARAM_NAMES)]
    if not ratios:
        return Progress(level, "every parameter (no fit)", np.inf, False, lost=lost)
    ratio, worst = max(ratios, key=lambda p: p[0] if np.isfinite(p[0]) else np.inf)
    firm = fitted and bool(ratio <= 1.0)
    return Progress(level, worst, ratio, level == GOOD and firm and not broken, firm, broken,
                    lost)


# A parameter this many standard errors past its limit cannot come back within it: more data
# shrink the standard error, they do not move the estimate by more than a few of them (for
# normal errors, 5 leaves a chance of 3e-7 per parameter and fit; method.md §13).
LOST_Z = 5.0

# Each parameter limit: the sensor, the unit the row's raw unit must be, the names, and the
# factor from the row's value to the limit's unit (a function of the raw unit for the bias).
_PARAM_LIMITS = {
    "acc_bias_mg": ("acc", ("g", "m/s^2"), ACC_PARAM_NAMES[6:]),
    "acc_scale_pct": ("acc", ("g", "m/s^2"), ACC_PARAM_NAMES[3:6]),
    "acc_misalignment_mrad": ("acc", None, ACC_PARAM_NAMES[:3]),
    "gyro_bias_dps": ("gyro", ("rad/s",), ("b_x", "b_y", "b_z")),
    "gyro_scale_pct": ("gyro", ("rad/s",), GYRO_PARAM_NAMES[6:9]),
    "gyro_misalignment_mrad": ("gyro", None, GYRO_PARAM_NAMES[:6]),
}


UNITS = {"acc_bias_mg": "mg", "acc_scale_pct": "%", "acc_misalignment_mrad": "mrad",
         "gyro_bias_dps": "deg/s", "gyro_scale_pct": "%", "gyro_misalignment_mrad": "mrad"}


def lost_limits(limits: dict[str, float], row: dict) -> list[str]:
    """The ``limits`` (a spec's) that the running calibration ``row`` (imucal.capture.running)
    can no longer meet (method.md §13): a parameter whose value is past its limit by more than
    ``LOST_Z`` standard errors (one the data do not determine yet is never lost: more poses may
    determine it), and the still-norm error when the floor of the block means' scatter is at
    or over its limit. The held-out gravity error is not judged early: slower or different
    turns can lower it."""
    from imucal.session import STANDARD_GRAVITY

    out = []
    for key, limit in limits.items():
        if key == "static_norm_error_mg":
            floor = row.get("static_norm_floor_mg")
            if floor is not None and floor >= limit:
                out.append(f"{key}: the still poses scatter by at least {floor:.3g} mg beyond "
                           f"their noise, which more data do not remove (limit {limit:g})")
            continue
        if key not in _PARAM_LIMITS:
            continue
        sensor, units, names = _PARAM_LIMITS[key]
        unit = row.get(f"{sensor}_unit_raw")
        if unit is None or (units is not None and unit not in units):
            continue
        k = {"acc_bias_mg": 1e3 / (STANDARD_GRAVITY if unit == "m/s^2" else 1.0),
             "gyro_bias_dps": 180.0 / np.pi}.get(key, 1e3 if "misalignment" in key else 100.0)
        for name in names:
            v, sd = row.get(f"{sensor}_{name}"), row.get(f"{sensor}_std_{name}")
            if v is None or sd is None or not np.isfinite(sd) or sd <= 0:
                continue
            v = (v - 1.0 if "scale" in key else v) * k
            z = (abs(v) - limit) / (sd * k)
            if z > LOST_Z:
                out.append(f"{key}: {name} = {v:.4g} {UNITS[key]}, {z:.0f} standard errors "
                           f"past the limit {limit:g}")
    return out
