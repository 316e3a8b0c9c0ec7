"""A run as a person reads it: the sections of every summary, worded once.

The CLI prints a :class:`Report` as plain text (``imucal/cli/summary.py``) and the viewer as
markdown (``viewer/summary.py``); both take their sentences and numbers from here, so the two
never say different things. Layout (columns, tables, number precision of the tables) is
theirs; what is said is this module's. Text is ASCII, for any terminal.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from imucal.models import ACC_PARAM_NAMES, GYRO_PARAM_NAMES
from imucal.result import Result, Segment
from imucal.stages.accel import AccFit
from imucal.stages.gyro import GyroFit
from imucal.stages.quality import BeforeAfter
from imucal.warning import RunWarning


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
    span: str  # "0.0-179.7 s, 36 blocks, 30 orientations"
    fits: tuple[FitSection, ...]  # the accelerometer's, then the gyroscope's if any


@dataclass(frozen=True)
class Report:
    title: str  # the source's file name
    overview: tuple[Line, ...]  # session, static blocks, segments, lambda, output
    quality: tuple[QualityRow, ...]
    quality_notes: tuple[str, ...]  # why a "before" is missing, ...
    segments: tuple[SegmentSection, ...]
    warnings: tuple[RunWarning, ...]
    guide: tuple[Line, ...] = ()  # "strong", "weak", "record next": the recording judged


def fmt(x: float | None, spec: str = ".6g") -> str:
    """A number for a summary; "n/a" where it has no value (None, NaN)."""
    if x is None or not math.isfinite(float(x)):
        return "n/a"
    return format(float(x), spec)


def report(result: Result) -> Report:
    """The summary of ``result``: overview, quality before/after, each segment's parameters,
    and the warnings."""
    q = result.quality
    quality = [
        QualityRow("static norm error (mg)", q.static_norm_rms_mg, "RMS over the block means",
                   q.static_norm_cv_mg),
        QualityRow("sample norm error (mg)", q.sample_norm_rms_mg, "single samples: sensor noise"),
    ]
    if q.gravity_angle_rms_deg is not None:
        quality.append(QualityRow("gravity angle (deg)", q.gravity_angle_rms_deg,
                                  "RMS over the rotations: measured vs integrated",
                                  q.gravity_angle_cv_deg))
    return Report(title=Path(result.session.source).name, overview=_overview(result),
                  quality=tuple(quality), quality_notes=tuple(q.notes),
                  segments=tuple(_segment(result, seg) for seg in result.segments),
                  warnings=tuple(result.warnings), guide=_guide(result))


def _overview(result: Result) -> tuple[Line, ...]:
    s, det, cal = result.session, result.detection, result.calibration
    gyro = (f"gyroscope {len(s.gyro)} samples at {_rate(s.gyro_rate)} ({s.gyro_unit})"
            if s.has_gyro else "no gyroscope")
    lc = result.whole.lcurve
    how = (f"L-curve corner, point {lc.corner + 1} of {len(lc.lambdas)}" if lc is not None
           else "fixed")
    memory = (Line("memory", s.storage),) if s.storage else ()
    return (
        Line("session", f"{s.source}: {s.duration:.1f} s, accelerometer {len(s.acc)} samples at "
                        f"{_rate(s.acc_rate)} ({s.acc_unit}), {gyro}"),
        *memory,
        Line("static blocks", f"{len(det.blocks)} (window {det.window}, min length "
                              f"{det.min_len} samples)"),
        Line("segments", f"{len(result.segments)} ({result.grouping.mode})"),
        Line("lambda", f"{fmt(result.whole.lam, '.3g')} ({how})"),
        Line("output", f"calibrated accelerometer in {cal.acc_unit} (|g| = {cal.g:g})"
                       + (", gyroscope in rad/s" if s.has_gyro else "")),
    )


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
    span = (f"{seg.t_start:.1f}-{seg.t_end:.1f} s, {seg.n_blocks} blocks, "
            f"{seg.orientations} orientations")
    return SegmentSection(number=seg.number, span=span, fits=tuple(fits))


def _acc(fit: AccFit, unit: str, raw: str) -> FitSection:
    kinds = ["misalignment"] * 3 + ["scale"] * 3 + ["bias"] * 3
    units = ["rad"] * 3 + [f"{unit}/{raw}"] * 3 + [raw] * 3
    rows = tuple(ParamRow(n, k, u, float(v), float(e))
                 for n, k, u, v, e in zip(ACC_PARAM_NAMES, kinds, units, fit.params, fit.std))
    rep = fit.report
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
