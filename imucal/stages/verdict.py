"""One verdict on a run, first: ``good``, ``usable with caveats`` or ``not usable``, the one
reason that decides it and the next step (issue 21). Pure arithmetic on what the run has:
the held-out figures (method.md §5: each still pose, and each turn, predicted by a fit that did
not see it), the parameters the still poses cannot determine, and the guide to the recording
(:mod:`imucal.stages.guide`).

The held-out figures decide, because they are what a user gets on poses and turns the fit has
not seen; in-sample figures flatter a fit with few poses (the Ferraris session of
../shared/data: 0.226 mg in-sample, 16.9 mg held out). What a user of the field accepts:

- static norm error held out: the calibrated ``|a|`` of a still pose the fit did not see,
  against ``|g|``. A consumer MEMS accelerometer leaves the factory with zero-g offsets of
  20-80 mg per axis (MPU-6050, BMI160, LSM6DS datasheets), which its raw ``|a|`` shows (20-60
  mg on the shared recordings); a hand calibration reaches 0.1-0.3 mg held out on them (imu_tk
  reaches 0.11 mg in-sample on its own Xsens file). Held out above ACC_CAVEAT_MG the
  calibration still removes most of the factory error but is well off what the method gives;
  above ACC_POOR_MG it is off by a sizeable part of the error it was meant to remove.
- gravity prediction error held out: the angle between a still pose's gravity and the one the
  calibrated gyroscope carries there from the pose before (M5). A consumer gyroscope's scale
  tolerance is 1-3 % (the same datasheets): 1-3 deg over a 90-deg turn, as the raw sensor
  shows on the shared recordings (1.5-3.7 deg); calibrated, 0.05-0.53 deg held out.
- overfitting: held out much worse than in-sample (:attr:`AccCrossValidation.overfitted`, and
  :data:`imucal.stages.gyro.OVERFIT_RATIO` for the turns), the same tests as the warnings.
- parameters the data do not determine (issue 27): a held-out figure is no verdict on a
  direction no pose or turn measured, since leaving one block out cannot show what no block
  saw (a coplanar session: 0.56 mg held out, 22 mg RMS in truth). A parameter whose data-only
  standard error would let a pose or a turn along its direction pass the not-usable limit
  (:data:`imucal.stages.accel.UNDETERMINED_STD`, :data:`imucal.stages.gyro.UNDETERMINED_TURN_DEG`)
  makes the run not usable, whatever the figures: the prior held it, nothing measured it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from imucal.stages.accel_cv import AccCrossValidation, axis_words
from imucal.stages.drift import ADVICE as DRIFT_ADVICE
from imucal.stages.drift import ADVICE_IN_TEMPERATURE
from imucal.stages.guide import MIN_TILT_DEG, ORIENTATIONS_NEEDED, Guide
from imucal.stages.gyro import OVERFIT_RATIO as GYRO_OVERFIT_RATIO
from imucal.stages.gyro import GyroFit
from imucal.warning import RunWarning

GOOD = "good"
CAVEATS = "usable with caveats"
NOT_USABLE = "not usable"
LEVELS = (GOOD, CAVEATS, NOT_USABLE)  # in order of harm

# Held-out static norm error, mg (see the module's docstring). 2 mg is about ten times what a
# good hand calibration reaches held out (0.16-0.32 mg on the shared recordings) and a tenth of
# the factory offsets it removes; 10 mg is half of the smallest factory error a raw sensor
# showed here (21 mg) and about 0.6 deg of tilt.
ACC_CAVEAT_MG = 2.0
ACC_POOR_MG = 10.0
# Held-out gravity prediction error, deg: above 1 deg a 90-deg turn is carried with more error
# than a 1 % scale error gives, the low end of the raw tolerance; above 3 deg no better than
# an uncalibrated gyroscope within its datasheet (1-3 % of a 90-deg turn).
GYRO_CAVEAT_DEG = 1.0
GYRO_POOR_DEG = 3.0

# A drift's next step, by the advice its warning ends with (imucal.stages.drift): a steady
# bias that moved, or one the temperature model does not explain (method.md §8, §12).
DRIFT_NEXT = {DRIFT_ADVICE: "let the sensor warm up (run it 10-15 minutes) before recording, "
                            "and keep the session short",
              ADVICE_IN_TEMPERATURE: "check that the temperature stream is the sensor's own, "
                                     "and keep the session short"}


@dataclass(frozen=True)
class Finding:
    """One thing the verdict weighs: how bad, why, and what to do about it."""

    code: str  # stable, for scripts: "acc_held_out", "gyro_overfitted", ...
    level: str  # one of LEVELS
    reason: str  # one sentence for a person
    next_step: str  # what to do, as an instruction

    def to_dict(self) -> dict[str, str]:
        return {"code": self.code, "level": self.level, "reason": self.reason,
                "next": self.next_step}


@dataclass(frozen=True)
class Verdict:
    """The run judged: its level, the finding that decides it, and the others."""

    level: str  # GOOD, CAVEATS or NOT_USABLE
    reason: str  # the one reason that decides it
    next_step: str
    code: str  # the deciding finding's code; "good" when nothing weighs against the run
    caveats: tuple[Finding, ...] = ()  # every finding but the deciding one, worst first
    figures: dict[str, float | None] = field(default_factory=dict)  # what was judged
    spec: dict | None = None  # a maker's limits checked (with_spec): pass, broken, limits
    # The model the figures are of, where it is not the constant fit: "bias in temperature"
    # (method.md §8, §12: apply calibrates with it, so the verdict judges it).
    model: str | None = None

    @property
    def usable(self) -> bool:
        return self.level != NOT_USABLE

    @property
    def text(self) -> str:
        """"not usable: <reason>" in one line."""
        return f"{self.level}: {self.reason}"

    def to_dict(self) -> dict:
        """The calibration file's top-level ``verdict`` (JSON: no NaN)."""
        def f(x: float | None) -> float | None:
            return None if x is None or not np.isfinite(x) else float(x)

        return {"level": self.level, "reason": self.reason, "next": self.next_step,
                "code": self.code, "caveats": [c.to_dict() for c in self.caveats],
                "figures": {k: f(v) for k, v in self.figures.items()},
                "thresholds": {"acc_held_out_mg": {"caveats": ACC_CAVEAT_MG,
                                                   "not_usable": ACC_POOR_MG},
                               "gravity_held_out_deg": {"caveats": GYRO_CAVEAT_DEG,
                                                        "not_usable": GYRO_POOR_DEG}}} | (
            {} if self.spec is None else {"spec": self.spec}) | (
            {} if self.model is None else {"model": self.model})


@dataclass(frozen=True)
class SegmentFigures:
    """What the verdict reads of one segment (:class:`imucal.result.Segment`)."""

    number: int | None  # from 1; None when the session is one segment (it is not named)
    acc_cv: AccCrossValidation
    gyro: GyroFit | None
    orientations: int
    # What the accelerometer's figures are of, in the verdict's words: the constant fit, or
    # "the fit in temperature" (its bias in temperature, method.md §8, §12).
    acc_fit: str = "the fit"


def judge(segments: Sequence[SegmentFigures], guide: Guide | None,
          drifts: Sequence[RunWarning] = (), model: str | None = None) -> Verdict:
    """The verdict of a run: every finding, the worst decides (ties: the first found, in the
    order accelerometer held out, gyroscope held out, undetermined parameters, poses, drifts,
    turns). ``drifts`` are the warnings of a bias that moved within a segment
    (:mod:`imucal.stages.drift`): caveats, since one calibration was fitted to a sensor that
    changed, and the held-out figures average over the change instead of showing it.
    ``model`` names the model the segments' figures are of where it is not the constant fit
    (the bias in temperature, method.md §8)."""
    findings: list[Finding] = []
    figures: dict[str, float | None] = {}
    for seg in segments:
        findings += _accelerometer(seg, guide, figures)
        if seg.gyro is not None:
            findings += _gyroscope(seg, guide, figures)
    for w in drifts:
        advice = next((a for a in DRIFT_NEXT if w.text.endswith(f"; {a}")), DRIFT_ADVICE)
        findings.append(Finding(w.code, CAVEATS, w.text.removesuffix(f"; {advice}"),
                                DRIFT_NEXT[advice]))
    if guide is not None:
        findings += _recording(guide)
    if not findings:
        words = segments[0].acc_fit if segments else "the fit"
        return Verdict(GOOD, _good_reason(figures, words), "none: the calibration is ready to use",
                       GOOD, (), figures, model=model)
    ranked = sorted(findings, key=lambda f: -LEVELS.index(f.level))  # stable: order kept
    top = ranked[0]
    return Verdict(top.level, top.reason, top.next_step, top.code, tuple(ranked[1:]), figures,
                   model=model)


def with_spec(verdict: Verdict, check: dict, source: str) -> Verdict:
    """The verdict with a maker's limits applied (``check`` as :mod:`imucal.fleet.spec` gives
    it: ``pass``, ``broken``, ``unchecked``, and the ``limits``): a unit out of its limits is
    not usable whatever the calibration's quality, and so is one the limits could not judge
    (a spec passes only what it judged). The limit it breaks (else the first it could not
    judge) is the reason; the calibration's own verdict becomes the first of the others."""
    verdict = replace(verdict, spec=dict(check) | {"file": source})
    broken = list(check.get("broken") or [])
    unchecked = list(check.get("unchecked") or [])
    if not broken and not unchecked:
        return verdict
    own = Finding(verdict.code, verdict.level, verdict.reason, verdict.next_step)
    if broken:
        more = f" (and {len(broken) - 1} more)" if len(broken) > 1 else ""
        return replace(verdict, level=NOT_USABLE, code="out_of_spec",
                       reason=f"out of the limits of {source}: {broken[0]}{more}",
                       next_step="set the unit aside, or widen the limits if they are wrong",
                       caveats=(own, *verdict.caveats))
    return replace(verdict, level=NOT_USABLE, code="spec_unchecked",
                   reason=(f"the limits of {source} could not be judged on this session: "
                           f"{', '.join(unchecked)} (no figure to compare)"),
                   next_step=("remove the limits this session cannot be judged on, or record "
                              "what they need (the unit's nominal scale, a gyroscope)"),
                   caveats=(own, *verdict.caveats))


def _good_reason(figures: dict[str, float | None], acc_fit: str = "the fit") -> str:
    """The held-out figures that passed: the worst segment's where there are several."""
    def worst(name: str) -> float | None:
        found = [v for k, v in figures.items()
                 if k.endswith(name) and v is not None and np.isfinite(v)]
        return max(found) if found else None

    acc, gyro = worst("acc_held_out_mg"), worst("gravity_held_out_deg")
    # The same words as a finding's, with the figures that passed (RMS over the poses/turns).
    parts = ([f"still poses {acc_fit} did not see are off by {acc:.2g} mg"] if acc is not None
             else [])
    if gyro is not None:
        parts.append(f"turns it did not see end {gyro:.2g} deg off the measured gravity")
    return "; ".join(parts) or "every check passed"


def _where(seg: SegmentFigures) -> str:
    return "" if seg.number is None else f"segment {seg.number}: "


def _key(seg: SegmentFigures, name: str) -> str:
    return name if seg.number is None else f"segment_{seg.number}_{name}"


def _poses_next(guide: Guide | None, orientations: int) -> str:
    """"record 6 more poses: with (-y, +z), ... pointing up": the guide's poses (the greedy
    cover of the directions no pose comes near), else a count."""
    if guide is not None and len(guide.poses.suggested):
        s = guide.poses.suggested
        where = ", ".join(f"({axis_words(v)})" for v in s)
        return (f"record {len(s)} more pose{'s' if len(s) > 1 else ''}: with {where} "
                "pointing up")
    n = max(ORIENTATIONS_NEEDED - orientations, 3)
    return f"record {n} more poses, each in a new orientation, spread over all directions"


def _turns_next(guide: Guide | None) -> str:
    t = None if guide is None else guide.turns
    if t is not None and t.fast.any():
        return (f"turn more slowly between poses: below {t.rate_limit:.3g} rad/s "
                f"({np.degrees(t.rate_limit):.0f} deg/s)")
    if t is not None and t.small.any():
        return (f"record more turns, each tilting the device {MIN_TILT_DEG:g} deg or more, "
                "about every axis")
    return "record more turns between poses, about every axis"


def _accelerometer(seg: SegmentFigures, guide: Guide | None,
                   figures: dict[str, float | None]) -> list[Finding]:
    cv = seg.acc_cv
    held, ins = cv.rms_mg, cv.in_sample_rms_mg
    figures[_key(seg, "acc_held_out_mg")] = held
    figures[_key(seg, "acc_in_sample_mg")] = ins
    where, out = _where(seg), []
    poses = _poses_next(guide, seg.orientations)
    if not np.isfinite(held):
        return [Finding("acc_unchecked", CAVEATS, f"{where}the accelerometer fit could not be "
                        "checked on still poses it did not see", poses)]
    why = ""
    if seg.orientations < ORIENTATIONS_NEEDED:
        why = f": {seg.orientations} distinct orientations ({ORIENTATIONS_NEEDED} needed)"
    if cv.undetermined:
        why += (" leave " if why else ": the poses leave ") + (
            f"{', '.join(cv.undetermined)} undetermined")
    said = (f"{'overfitted: ' if cv.overfitted else ''}still poses {seg.acc_fit} did not see are "
            f"off by {held:.3g} mg, against {ins:.3g} mg on those it saw{why}")
    if held > ACC_POOR_MG:
        out.append(Finding("acc_held_out", NOT_USABLE, where + said, poses))
    elif held > ACC_CAVEAT_MG:
        out.append(Finding("acc_held_out", CAVEATS, where + said, poses))
    elif cv.overfitted:
        out.append(Finding("acc_overfitted", CAVEATS, where + said, poses))
    if cv.undetermined:
        out.append(Finding("acc_undetermined", NOT_USABLE,
                           f"{where}the still poses do not determine "
                           f"{', '.join(cv.undetermined)}: kept near the nominal value, "
                           "not measured; a pose along the directions they govern may be off "
                           f"by more than {ACC_POOR_MG:g} mg, which the figures cannot show "
                           "(no pose measured them)", poses))
    if seg.orientations < ORIENTATIONS_NEEDED:
        out.append(Finding("few_orientations", CAVEATS,
                           f"{where}{seg.orientations} distinct orientations: "
                           f"{ORIENTATIONS_NEEDED} or more determine the accelerometer's "
                           "9 parameters", poses))
    return out


def _gyroscope(seg: SegmentFigures, guide: Guide | None,
               figures: dict[str, float | None]) -> list[Finding]:
    g = seg.gyro
    assert g is not None
    fitted = ~g.excluded
    ins = (float(np.sqrt(np.mean(np.square(g.angle_after[fitted])))) if fitted.any()
           else float("nan"))
    held = g.cv.rms
    figures[_key(seg, "gravity_held_out_deg")] = held
    figures[_key(seg, "gravity_in_sample_deg")] = ins
    where, turns = _where(seg), _turns_next(guide)
    weak = [] if not g.undetermined else [Finding(
        "gyro_undetermined", NOT_USABLE,
        f"{where}the turns do not determine the gyroscope's {', '.join(g.undetermined)}: kept "
        "near the nominal value, not measured; a turn about the axes they govern may end more "
        f"than {GYRO_POOR_DEG:g} deg off, which the figures cannot show (no turn measured them)",
        "record turns about every axis: tip the device forward, sideways and around")]
    if not np.isfinite(held):
        return [Finding("gyro_unchecked", CAVEATS, f"{where}the gyroscope fit could not be "
                        "checked on turns it did not see (too few turns)", turns), *weak]
    overfitted = ins > 0 and held > GYRO_OVERFIT_RATIO * ins
    said = (f"{'overfitted: ' if overfitted else ''}turns the gyroscope fit did not see end "
            f"{held:.2g} deg off the measured gravity, against {ins:.2g} deg for those it saw")
    if held > GYRO_POOR_DEG:
        return [Finding("gyro_held_out", NOT_USABLE, where + said, turns), *weak]
    if held > GYRO_CAVEAT_DEG:
        return [Finding("gyro_held_out", CAVEATS, where + said, turns), *weak]
    if overfitted:
        return [Finding("gyro_overfitted", CAVEATS, where + said, turns), *weak]
    return weak


def _recording(guide: Guide) -> list[Finding]:
    """What the guide finds that weighs on the result itself. Holds and small turns only
    shape the next recording's advice (the blocks and turns that counted were fine); so does
    a sphere not quite covered (below GOOD_COVERAGE) where the poses determine every
    parameter: the held-out error already says how well the fit reaches poses it did not
    see (a synthetic session with 24 orientations and 93.5 % coverage: 0.2 mg held out).
    Turns faster than the limit or through clipped samples weigh: the integration (M5) of
    the first is off, the second are left out of the fit."""
    out = []
    t = guide.turns
    n_fast, n_sat = int(t.fast.sum()), int(t.saturated.sum())
    if n_fast or n_sat:
        what = ", ".join(x for x in (f"{n_fast} faster than {t.rate_limit:.3g} rad/s"
                                     if n_fast else "",
                                     f"{n_sat} through clipped samples" if n_sat else "") if x)
        out.append(Finding("turns_too_fast", CAVEATS,
                           f"{what} of {len(t.peak_rate)} turns: the gyroscope's fit "
                           "rests on the others", _turns_next(guide)))
    return out
