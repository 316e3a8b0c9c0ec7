"""A run as a person reads it: the sections of every summary, worded once.

The CLI prints a :class:`Report` as plain text (``imucal/cli/summary.py``) and the viewer as
markdown (``viewer/summary.py``); both take their sentences and numbers from here, so the two
never say different things. Layout (columns, tables, number precision of the tables) is
theirs; what is said is this module's. Text is ASCII, for any terminal.

The verdict comes first, then what a firmware engineer needs in their own words; the method's
own vocabulary (the detector's window, the grouping's test, the L-curve, the fits' costs) is in
``details`` and each fit's ``details``: the CLI prints them with ``-v``, the viewer at the end,
and calib.json holds them all.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from imucal.errors import plural
from imucal.models import ACC_PARAM_NAMES, GYRO_PARAM_NAMES
from imucal.result import Result, Segment
from imucal.stages.accel import AccFit
from imucal.stages.gyro import GyroFit
from imucal.stages.quality import BeforeAfter
from imucal.stages.triads import angle_deg
from imucal.warning import RunWarning

# M8s's design effect from which the overview says the magnetometer's residual is slow (its
# standard errors twice the white ones or more)
SAID_DESIGN_EFFECT = 4.0


@dataclass(frozen=True)
class Line:
    """One labelled line of the overview ("session", "static blocks", "lambda", ...)."""

    label: str
    text: str


@dataclass(frozen=True)
class QualityRow:
    label: str  # with its unit: "static norm error (mg)"
    figure: BeforeAfter
    note: str  # what the figure is made of, in a few words
    held_out: float | None = None  # the "after" figure out of sample (method.md §5)


@dataclass(frozen=True)
class ParamRow:
    name: str  # as in ACC_PARAM_NAMES / GYRO_PARAM_NAMES, "b_x".. for the gyroscope bias
    kind: str  # "misalignment", "scale" or "bias"
    unit: str  # "" where the parameter has none
    value: float
    std: float | None  # None where the fit gives none (a bias measured, not fitted)


@dataclass(frozen=True)
class FitSection:
    sensor: str  # "accelerometer" or "gyroscope"
    model: str  # the equation and the calibrated unit
    raw_unit: str
    params: tuple[ParamRow, ...]
    details: str  # how the fit went: lambda, start, costs, data

    def values(self, kind: str) -> np.ndarray:
        return np.array([p.value for p in self.params if p.kind == kind])

    def names(self, kind: str) -> list[str]:
        return [p.name for p in self.params if p.kind == kind]


@dataclass(frozen=True)
class SegmentSection:
    number: int  # from 1, as everywhere (:attr:`imucal.result.Segment.number`)
    span: str  # "0.0-179.7 s, 36 still poses, 30 orientations"
    fits: tuple[FitSection, ...]  # the accelerometer's, then the gyroscope's if any


@dataclass(frozen=True)
class Report:
    title: str  # the source's file name
    overview: tuple[Line, ...]  # session, still poses, segments, output: plain words
    quality: tuple[QualityRow, ...]
    quality_notes: tuple[str, ...]  # why a "before" is missing, ...
    segments: tuple[SegmentSection, ...]
    warnings: tuple[RunWarning, ...]
    guide: tuple[Line, ...] = ()  # "strong", "weak", "record next": the recording judged
    verdict: tuple[Line, ...] = ()  # "verdict", "next step", then "also" per other finding
    details: tuple[Line, ...] = ()  # the method's own terms: detector, grouping, lambda


# Under the quality table: what "held out" means (method.md §5), in a line.
HELD_OUT_NOTE = "held out: each still pose and turn predicted by a fit that did not see it"


def fmt(x: float | None, spec: str = ".6g") -> str:
    """A number for a summary; "n/a" where it has no value (None, NaN)."""
    if x is None or not math.isfinite(float(x)):
        return "n/a"
    return format(float(x), spec)


def report(result: Result) -> Report:
    """The summary of ``result``: overview, quality before/after, each segment's parameters,
    and the warnings."""
    q = result.quality
    heat = in_temperature(result)
    quality = [
        QualityRow("static norm error (mg)", q.static_norm_rms_mg,
                   "|a| against |g| on the still poses, RMS" if heat is None else
                   "constant bias: |a| against |g| on the still poses, RMS", q.static_norm_cv_mg),
        *(() if heat is None else (QualityRow(
            # "before" where its blocks are the run's (not several sessions' pooled)
            "  in temperature (mg)", BeforeAfter(q.static_norm_rms_mg.before if heat[2] == len(
                result.block_times) else None, heat[0]),
            "bias in temperature (M16), as apply calibrates: the figures the verdict judges",
            heat[1]),)),
        QualityRow("sample norm error (mg)", q.sample_norm_rms_mg,
                   "the same on single samples: mostly the sensor's noise"),
    ]
    if q.gravity_angle_rms_deg is not None:
        quality.append(QualityRow("gravity angle (deg)", q.gravity_angle_rms_deg,
                                  ("" if heat is None else "constant bias: ")
                                  + "gravity the gyroscope carries through each turn against "
                                  "the gravity measured after it, RMS", q.gravity_angle_cv_deg))
    return Report(title=Path(result.session.source).name, overview=_overview(result),
                  quality=tuple(quality), quality_notes=tuple(q.notes),
                  segments=tuple(_segment(result, seg) for seg in result.segments),
                  warnings=tuple(result.warnings), guide=_guide(result),
                  verdict=_verdict(result), details=_details(result))


def in_temperature(result: Result) -> tuple[float, float, int, int] | None:
    """The accelerometer's static norm error (mg RMS) with its bias in temperature, in sample
    and held out, over how many still blocks, and how many of them were scored held out (a
    ramp's end blocks are not; method.md §8, §12); None where the run has no such model (the
    constant fit's figures are then the only ones)."""
    for f in result.temperature:
        if f.sensor == "accelerometer" and f.held_out_mg is not None and f.after_mg is not None:
            held = f.held_out_mg[np.isfinite(f.held_out_mg)]
            return (float(np.sqrt(np.mean(f.after_mg ** 2))),
                    float(np.sqrt(np.mean(held ** 2))) if len(held) else float("nan"),
                    len(f.after_mg), len(held))
    return None


def _overview(result: Result) -> tuple[Line, ...]:
    s, det, cal = result.session, result.detection, result.calibration
    gyro = (f"gyroscope {len(s.gyro)} samples at {_rate(s.gyro_rate)} ({s.gyro_unit})"
            if s.has_gyro else "no gyroscope")
    memory = (Line("memory", s.storage),) if s.storage else ()
    segs = result.segments
    if len(segs) == 1:
        seg_text = "1: one calibration for the whole recording"
    else:
        starts = ", ".join(f"{seg.number} from {seg.t_start:.1f} s" for seg in segs[1:])
        seg_text = (f"{len(segs)}: the sensor's errors changed during the recording, so each "
                    f"part has its own calibration (segment 1 from the start, {starts})")
    return (
        Line("session", f"{s.source}: {s.duration:.1f} s, accelerometer {len(s.acc)} samples at "
                        f"{_rate(s.acc_rate)} ({s.acc_unit}), {gyro}"),
        *memory,
        Line("still poses", f"{len(det.blocks)} found"),
        Line("segments", seg_text),
        Line("output", f"calibrated accelerometer in {cal.acc_unit} (|g| = {cal.g:g})"
                       + (", gyroscope in rad/s" if s.has_gyro else "")),
        *_magnetometer(result),
        *_triads(result),
        *(Line("temperature", n) for f in result.temperature for n in f.notes),
    )


def _magnetometer(result: Result) -> tuple[Line, ...]:
    """The magnetometer in a line (M8, stages/mag.py): its field, the norm's error in and out
    of sample, the directions reached; or why it was not calibrated."""
    stream = result.session.magnetometer
    if stream is None:
        return ()
    fit = result.magnetometer
    if fit is None:
        why = [w.message for w in result.warnings if w.code == "mag_not_calibrated"]
        return (Line("magnetometer", why[0] if why else f"{stream.name}: not calibrated"),)
    q, unit = fit.quality, fit.unit or "raw units"
    dip = "" if fit.dip_deg is None else f", dip {fit.dip_deg:.1f} deg"
    if fit.alignment is not None:  # what determined R_am (M8, M8t)
        dip += f", rotation from the {fit.alignment.evidence}"
    held = ("" if q.norm_rms_held_out_pct is None
            else f" ({fmt(q.norm_rms_held_out_pct, '.2g')} % held out)")
    left = (f"; {len(fit.disturbances)} disturbed interval(s) left out"
            if fit.disturbances else "")
    # M8s: a residual that follows the path makes the samples far fewer than they look; said
    # where it doubles the standard errors or more (white noise: about 1x)
    slow = ("" if fit.se_design_effect < SAID_DESIGN_EFFECT else
            f"; the norm's error is slow (correlated over {fit.se_block_s:.2g} s): standard "
            f"errors {np.sqrt(fit.se_design_effect):.0f}x those of independent samples")
    return (Line("magnetometer", f"{fit.stream}: field {fmt(fit.field, '.4g')} {unit}{dip}; "
                                 f"|m| within {fmt(q.norm_rms_pct, '.2g')} % of it{held}; "
                                 f"{q.coverage:.0%} of directions reached{left}{slow}"),)


def _triads(result: Result) -> tuple[Line, ...]:
    """The other triads (method.md §11): each one's rotation to the reference and how well the
    two agree once calibrated, then what was said about it."""
    out = []
    for tri in result.triads:
        a, res = tri.agreement, tri.result
        own = ("" if res is None or res.verdict is None
               else f"; its own verdict: {res.verdict.level}")
        if a is None:
            text = "calibrated, not rotated" if res is not None else "not calibrated"
        else:
            text = (f"turned {a.angle_deg:.3f} deg from the reference (+- "
                    f"{fmt(a.rotation.std_total_deg, '.3f')} deg, {a.blocks} shared still "
                    f"poses); the "
                    f"two agree within {a.held_out_rms_mg:.3g} mg RMS on poses held out "
                    f"(before calibration {a.before_rms_mg:.3g} mg)")
        out.append(Line("triad", f"{tri.name}: {text}{own}"))
        if tri.gyro_agreement is not None:
            g = tri.gyro_agreement
            versus = ("" if g.accel_difference_deg is None
                      else f", {g.accel_difference_deg:.3f} deg from its accelerometer's rotation")
            out.append(Line("triad", f"{tri.gyro}: turned {angle_deg(np.eye(3), g.rotation.R):.3f}"
                            f" deg from the reference's gyroscope (+- "
                            f"{fmt(g.rotation.std_total_deg, '.3f')} deg, {g.turns} turns)"
                            f"{versus}"))
        v = tri.against_reference
        if v is not None and res is not None:
            own = res.segments[0].acc.model
            dk = float(np.max(np.abs(v.model.K / own.K - 1))) * 1e6
            db = float(np.max(np.abs(own.matrix @ (v.model.b - own.b)))) / res.calibration.g * 1e3
            out.append(Line("triad", f"{tri.name} fitted to the reference's gravity vectors: "
                            f"scales within {dk:.0f} ppm and bias within {db:.3g} mg of its own "
                            f"fit ({v.rms_mg:.3g} mg RMS over {v.blocks} still poses)"))
        out += [Line("triad", t) for t in tri.said]
    if result.combined is not None:  # a low-range and a high-range pair (M18)
        out += [Line("triad", t) for t in result.combined.said]
    return tuple(out)


def _details(result: Result) -> tuple[Line, ...]:
    """The method's own terms (method.md §1-§3): the detector's values, how the segments were
    found, the accelerometer's lambda and how it was chosen."""
    det = result.detection
    lc = result.whole.lcurve
    how = (f"L-curve corner, point {lc.corner + 1} of {len(lc.lambdas)}" if lc is not None
           else "fixed")
    return (
        Line("detector", f"{plural(len(det.blocks), 'static block')} (window {det.window}, "
                         f"min length {det.min_len} samples, k {fmt(det.k, '.3g')})"),
        Line("grouping", result.grouping.mode),
        Line("lambda", f"{fmt(result.whole.lam, '.3g')} ({how})"),
    )


def _verdict(result: Result) -> tuple[Line, ...]:
    """The verdict (:mod:`imucal.stages.verdict`): level and reason, the next step, and the
    other findings, one line each."""
    v = result.verdict
    if v is None:
        return ()
    return (Line("verdict", v.text), Line("next step", v.next_step),
            *(Line("also", c.reason) for c in v.caveats))


def _guide(result: Result) -> tuple[Line, ...]:
    """The recording judged (:mod:`imucal.stages.guide`): what is strong, what is weak, and
    what to record next."""
    g = result.guide
    if g is None:
        return ()
    return tuple([Line("strong", t) for t in g.strong] + [Line("weak", t) for t in g.weak]
                 + [Line("record next", t) for t in g.record_next])


def _rate(hz: float | None) -> str:
    return "n/a" if hz is None else f"{hz:.4g} Hz"


def _segment(result: Result, seg: Segment) -> SegmentSection:
    fits = [_acc(seg.acc, result.calibration.acc_unit, result.session.acc_unit)]
    if seg.gyro is not None:
        fits.append(_gyro(seg.gyro, result.session.gyro_unit))
    span = (f"{seg.t_start:.1f}-{seg.t_end:.1f} s, {seg.n_blocks} still poses, "
            f"{seg.orientations} orientations")
    return SegmentSection(number=seg.number, span=span, fits=tuple(fits))


def _acc(fit: AccFit, unit: str, raw: str) -> FitSection:
    kinds = ["misalignment"] * 3 + ["scale"] * 3 + ["bias"] * 3
    units = ["rad"] * 3 + [f"{unit}/{raw}"] * 3 + [raw] * 3
    rows = tuple(ParamRow(n, k, u, float(v), float(e))
                 for n, k, u, v, e in zip(ACC_PARAM_NAMES, kinds, units, fit.params, fit.std))
    rep = fit.report
    # The method's terms (method.md §3): shown with -v, and at the end of the viewer's summary.
    starts = ", ".join(f"{k} {fmt(v, '.3g')}" for k, v in fit.starts.items())
    details = (f"lambda {fmt(fit.lam, '.3g')}; from the {rep.start_name} start (cost reached "
               f"from each start: {starts}); cost {fmt(rep.cost_start, '.3g')} -> "
               f"{fmt(rep.cost, '.3g')}; {fit.n_points} points from {fit.n_blocks} blocks")
    return FitSection("accelerometer", f"a = T K (a_raw - b), a in {unit}", raw, rows, details)


def _gyro(fit: GyroFit, raw: str) -> FitSection:
    scale_unit = f"rad/s per {raw}" if raw != "rad/s" else ""
    rows = [ParamRow(n, "misalignment" if i < 6 else "scale", "rad" if i < 6 else scale_unit,
                     float(v), float(e))
            for i, (n, v, e) in enumerate(zip(GYRO_PARAM_NAMES, fit.params, fit.std))]
    bias_std = fit.std[9:12] if len(fit.std) > 9 else [None] * 3
    rows += [ParamRow(n, "bias", raw, float(v), None if e is None else float(e))
             for n, v, e in zip(("b_x", "b_y", "b_z"), fit.model.b, bias_std)]
    rep = fit.report
    out = int(fit.excluded.sum())  # saturated or without gyroscope data (stages/sanity.py)
    details = (f"bias: {fit.bias_source}; lambda {fmt(fit.lam, '.3g')}; {len(fit.u_meas)} "
               f"rotations{f' ({out} left out of the fit)' if out else ''}; cost "
               f"{fmt(rep.cost_start, '.3g')} -> {fmt(rep.cost, '.3g')}")
    return FitSection("gyroscope", "w = T_g K_g (w_raw - b_g), w in rad/s", raw, tuple(rows),
                      details)
