"""The results as plain values (AnyValues, for scripts) and the markdown summary, which is
:mod:`imucal.report` laid out as markdown: the CLI prints the same report as text."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

import numpy as np
import rerun as rr

from imucal.models import ACC_PARAM_NAMES
from imucal.report import HELD_OUT_NOTE, Report, fmt, report

from . import paths as P
from .columns import nan_if_none

if TYPE_CHECKING:
    from imucal.result import Result


def log_results(result: Result, rec: rr.RecordingStream) -> None:
    s, q = result.session, result.quality
    for seg in result.segments:
        a = seg.acc
        rec.log(P.calibration(seg.number, "accelerometer"), rr.AnyValues(
            T=a.model.T.ravel(), K=a.model.K, b=a.model.b, params=a.params, std=a.std,
            param_names=list(ACC_PARAM_NAMES), **{"lambda": float(a.lam)},
            t_start=float(seg.t_start), t_end=float(seg.t_end), start=a.report.start_name,
            cost_start=float(a.report.cost_start), cost_end=float(a.report.cost),
            n_points=int(a.n_points), n_blocks=int(a.n_blocks),
            orientations=int(seg.orientations)), static=True)
        g = seg.gyro
        if g is not None:
            rec.log(P.calibration(seg.number, "gyroscope"), rr.AnyValues(
                T=g.model.T.ravel(), K=g.model.K, b=g.model.b, params=g.params,
                std=g.std, param_names=list(g.param_names), **{"lambda": float(g.lam)},
                bias_source=g.bias_source, nominal_scale=float(g.nominal_scale),
                transitions=int(len(g.u_meas)),
                transitions_excluded=int(np.count_nonzero(g.excluded)),
                cost_start=float(g.report.cost_start),
                cost_end=float(g.report.cost)), static=True)
    ga = q.gravity_angle_rms_deg
    rec.log(P.QUALITY, rr.AnyValues(
        static_norm_rms_mg_before=nan_if_none(q.static_norm_rms_mg.before),
        static_norm_rms_mg_after=nan_if_none(q.static_norm_rms_mg.after),
        sample_norm_rms_mg_before=nan_if_none(q.sample_norm_rms_mg.before),
        sample_norm_rms_mg_after=nan_if_none(q.sample_norm_rms_mg.after),
        gravity_angle_rms_deg_before=nan_if_none(None if ga is None else ga.before),
        gravity_angle_rms_deg_after=nan_if_none(None if ga is None else ga.after),
        block_norm_error_mg=np.asarray(q.block_norm_error_mg, float)), static=True)
    warnings = result.warnings
    rec.log(P.INFO, rr.AnyValues(
        source=s.source, sha256=s.sha256 or "-", acc_unit_raw=s.acc_unit,
        acc_unit=result.calibration.acc_unit, g=float(result.calibration.g),
        gyro_unit_raw=s.gyro_unit if s.has_gyro else "-", **{"lambda": float(result.whole.lam)},
        n_blocks=int(len(result.block_times)), n_segments=int(len(result.segments)),
        grouping=result.grouping.mode, settings=json.dumps(result.settings.to_dict()),
        n_warnings=int(len(warnings)),
        warnings=np.array([w.text for w in warnings] or [""], dtype=str),
        warning_codes=np.array([w.code for w in warnings] or [""], dtype=str)), static=True)
    rec.log(P.SUMMARY, rr.TextDocument(summary_markdown(result),
                                       media_type=rr.MediaType.MARKDOWN), static=True)


def summary_markdown(result: Result) -> str:
    """The calibration as a person reads it: quality first, then each segment's parameters."""
    return report_markdown(report(result))


def report_markdown(rep: Report) -> str:
    lines = [f"# IMU calibration: {rep.title}", ""]
    # The verdict first (Overview and Summary tabs show this document from its top).
    lines += [f"- **{line.label.capitalize()}:** {line.text}" for line in rep.verdict]
    lines += [""] if rep.verdict else []
    lines += [f"- **{line.label.capitalize()}:** {line.text}" for line in rep.overview]
    lines += ["", "## Quality", "", "| figure | before | after | held out |",
              "|---|---:|---:|---:|"]
    for row in rep.quality:
        held = "" if row.held_out is None else fmt(row.held_out, '.4g')
        lines.append(f"| {row.label} | {fmt(row.figure.before, '.4g')} | "
                     f"{fmt(row.figure.after, '.4g')} | {held} |")
    # What each figure measures, under the table: a narrow panel (the Overview's) then still
    # shows the numbers instead of cutting the table at its long first column.
    lines += ["", "; ".join(f"*{row.label}*: {row.note}" for row in rep.quality)
              + f"; *{HELD_OUT_NOTE}*", ""]
    lines += [f"- {n}" for n in rep.quality_notes]
    lines.append("")
    if rep.guide:
        lines += ["## Guide to the recording", ""]
        lines += [f"- **{line.label.capitalize()}:** {line.text}" for line in rep.guide] + [""]
    for seg in rep.segments:
        lines += [f"## Segment {seg.number}: {seg.span}", ""]
        for fit in seg.fits:
            lines += [f"### {fit.sensor.capitalize()}: {fit.model}", "",
                      "| parameter | value | std. error |", "|---|---:|---:|"]
            for p in fit.params:
                label = f"{p.name} ({p.unit})" if p.unit else p.name
                lines.append(f"| {label} | {fmt(p.value)} | {fmt(p.std, '.2g')} |")
            lines.append("")
    lines += ["## Warnings", ""]
    lines += [f"- {w.text}" for w in rep.warnings] or ["none"]
    lines.append("")
    # The method's own terms last, out of a first reader's way (the CLI's -v).
    lines += ["## Method details", ""]
    lines += [f"- **{line.label.capitalize()}:** {line.text}" for line in rep.details]
    for seg in rep.segments:
        lines += [f"- **Segment {seg.number}, {fit.sensor}:** {fit.details}" for fit in seg.fits]
    lines.append("")
    return "\n".join(lines)
