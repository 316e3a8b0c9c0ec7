"""The lines ``imucal calibrate`` prints about a run."""

from __future__ import annotations

from imucal.cli.outputs import fmt, fmt_rate, fmt_vec


def print_summary(result, written: list[str]) -> None:
    from imucal.models import acc_theta, gyro_theta

    s = result.session
    q = result.quality
    cal = result.calibration
    acc_raw = s.acc_unit
    gyro_raw = s.gyro_unit if s.has_gyro else None
    lines = []
    gyro_txt = (f"gyroscope {len(s.gyro)} samples at {fmt_rate(s.gyro_rate)} ({gyro_raw})"
                if s.has_gyro else "no gyroscope")
    lines.append(f"session         {s.source}: {s.duration:.1f} s, accelerometer {len(s.acc)} "
                 f"samples at {fmt_rate(s.acc_rate)} ({acc_raw}), {gyro_txt}")
    det = result.detection
    lines.append(f"static blocks   {len(det.blocks)} (window {det.window}, min length "
                 f"{det.min_len} samples)")
    lines.append(f"segments        {len(result.segments)} ({result.grouping.mode})")
    how = "L-curve corner" if result.settings.lam == "auto" else "fixed"
    lines.append(f"lambda          {fmt(result.whole.lam, '.3g')} ({how})")
    lines.append(f"{'':28s}{'before':>10s}{'after':>10s}")
    lines.append(f"{'static norm error (mg)':28s}{fmt(q.static_norm_rms_mg.before):>10s}"
                 f"{fmt(q.static_norm_rms_mg.after):>10s}")
    lines.append(f"{'sample norm error (mg)':28s}{fmt(q.sample_norm_rms_mg.before):>10s}"
                 f"{fmt(q.sample_norm_rms_mg.after):>10s}  (single samples: sensor noise)")
    if q.gravity_angle_rms_deg is not None:
        ga = q.gravity_angle_rms_deg
        lines.append(f"{'gravity angle (deg)':28s}{fmt(ga.before):>10s}{fmt(ga.after):>10s}")
    for seg in result.segments:
        lines.append(f"segment {seg.index}       {seg.t_start:.1f}-{seg.t_end:.1f} s, "
                     f"{seg.blocks[1] - seg.blocks[0]} blocks, {seg.orientations} orientations, "
                     f"lambda {fmt(seg.acc.lam)}, start {seg.acc.report.start_name}")
        th = acc_theta(seg.acc.model)
        lines.append(f"  acc   scale {fmt_vec(th[3:6])}  "
                     f"misalign(yz zy zx) {fmt_vec(th[0:3], '.3g')}"
                     f"  bias {fmt_vec(th[6:9])} {acc_raw}")
        if seg.gyro is not None:
            gt = gyro_theta(seg.gyro.model)
            lines.append(f"  gyro  scale {fmt_vec(gt[6:9])}  misalign {fmt_vec(gt[0:6], '.3g')}"
                         f"  bias {fmt_vec(seg.gyro.model.b)} {gyro_raw} "
                         f"({seg.gyro.bias_source})")
    lines.append(f"output          calibrated accelerometer in {cal.acc_unit} (|g| = "
                 f"{cal.g:g})" + (", gyroscope in rad/s" if s.has_gyro else ""))
    notes = [w.text for w in result.warnings] + list(q.notes)
    if notes:
        lines.append("warnings:")
        lines += [f"  - {w}" for w in notes]
    lines += [f"wrote {w}" for w in written]
    print("\n".join(lines))
