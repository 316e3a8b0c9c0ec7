"""The lines ``imucal calibrate`` prints about a run: :mod:`imucal.report` as plain text.

The verdict first, then the run in plain words; the method's own terms (the detector's
window, the grouping's test, the L-curve, the fits' costs) only with ``-v``."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from imucal.report import Report
    from imucal.result import Result

SHORT = {"accelerometer": "acc", "gyroscope": "gyro"}


def summary_lines(rep: Report, verbose: bool = False) -> list[str]:
    from imucal.report import HELD_OUT_NOTE, fmt

    lines = [f"{line.label:16s}{line.text}" for line in rep.verdict]
    lines += [f"{line.label:16s}{line.text}" for line in rep.overview]
    if verbose:
        lines += [f"{line.label:16s}{line.text}" for line in rep.details]
    lines.append(f"{'':28s}{'before':>10s}{'after':>10s}{'held out':>10s}")
    for row in rep.quality:
        held = "" if row.held_out is None else fmt(row.held_out, '.3g')
        lines.append(f"{row.label:28s}{fmt(row.figure.before, '.3g'):>10s}"
                     f"{fmt(row.figure.after, '.3g'):>10s}{held:>10s}  ({row.note})")
    lines.append(f"{'':16s}({HELD_OUT_NOTE})")
    for seg in rep.segments:
        lines.append(f"{'segment ' + str(seg.number):16s}{seg.span}")
        for fit in seg.fits:
            mis = " ".join(n.split("_")[1] for n in fit.names("misalignment"))
            lines.append(f"  {SHORT[fit.sensor]:6s}scale {_vec(fit.values('scale'))}  "
                         f"misalign({mis}) {_vec(fit.values('misalignment'), '.3g')}  "
                         f"bias {_vec(fit.values('bias'))} {fit.raw_unit}")
            if verbose:
                lines.append(f"{'':8s}{fit.details}")
    if rep.guide:
        lines.append("guide to the recording:")
        lines += [f"  {line.label:14s}{line.text}" for line in rep.guide]
    notes = [w.text for w in rep.warnings] + list(rep.quality_notes)
    if notes:
        lines.append("warnings:")
        lines += [f"  - {n}" for n in notes]
    return lines


def _vec(values, spec: str = ".6g") -> str:
    from imucal.report import fmt

    return " ".join(fmt(v, spec) for v in values)


def result_line(result: Result) -> str:
    """What a run came to, in one line: the verdict, the errors on still blocks and turns the
    fits did not see (method.md §5), then the in-sample ones. ``calibrate`` prints it above the
    files it wrote, ``imucal-view SESSION`` before the viewer opens."""
    from imucal.errors import plural
    from imucal.report import fmt, in_temperature

    q = result.quality
    parts = [f"accelerometer {fmt(q.static_norm_cv_mg, '.3g')} mg held out "
             f"({fmt(q.static_norm_rms_mg.after, '.3g')} in-sample)"]
    heat = in_temperature(result)
    if heat is not None:  # the figures the verdict judged first, the constant fit's beside
        parts = [f"accelerometer {fmt(heat[1], '.3g')} mg held out ({fmt(heat[0], '.3g')} "
                 f"in-sample) with its bias in temperature, {fmt(q.static_norm_cv_mg, '.3g')} "
                 f"({fmt(q.static_norm_rms_mg.after, '.3g')}) constant"]
    if q.gravity_angle_rms_deg is not None:
        parts.append(f"gyroscope {fmt(q.gravity_angle_cv_deg, '.3g')} deg held out "
                     f"({fmt(q.gravity_angle_rms_deg.after, '.3g')} in-sample)")
    lead = "" if result.verdict is None else f"{result.verdict.level}: "
    return (f"{'result':16s}{lead}{', '.join(parts)}; {plural(len(result.segments), 'segment')}, "
            f"{plural(len(result.block_times), 'still pose')}")


def print_summary(result: Result, written: list[str], verbose: bool = False) -> None:
    from imucal.report import report

    print("\n".join(summary_lines(report(result), verbose=verbose) + [result_line(result)]
                    + [f"wrote {w}" for w in written]))
