"""The summary (imucal/report.py): one report, printed by the CLI as text and by the viewer as
markdown, so the two say the same."""

from __future__ import annotations

import numpy as np
import pytest

import imucal
from imucal.cli.summary import summary_lines
from imucal.models import ACC_PARAM_NAMES, GYRO_PARAM_NAMES
from imucal.report import fmt, report
from viewer.summary import report_markdown


@pytest.fixture(scope="module")
def sample(sample_session_path):
    return imucal.calibrate(imucal.load_session(sample_session_path))


def test_report_rows_of_the_sample_session(sample):
    r = sample
    rep = report(r)
    assert rep.title == "session.mat"
    assert [line.label for line in rep.verdict] == ["verdict", "next step"]
    assert rep.verdict[0].text.startswith("good: ")
    assert [line.label for line in rep.overview] == ["session", "still poses", "segments",
                                                     "output"]
    text = dict((line.label, line.text) for line in rep.overview)
    s = r.session
    assert text["session"].startswith(f"session.mat: {s.duration:.1f} s, accelerometer "
                                      f"{len(s.acc)} samples at 100 Hz (g), gyroscope "
                                      f"{len(s.gyro)} samples at 100 Hz (rad/s)")
    assert text["still poses"] == f"{len(r.detection.blocks)} found"
    assert text["segments"] == "1: one calibration for the whole recording"
    # The method's own terms, for -v and the viewer's last section.
    detail = dict((line.label, line.text) for line in rep.details)
    assert detail["detector"] == (f"{len(r.detection.blocks)} static blocks (window "
                                  f"{r.detection.window}, min length {r.detection.min_len} "
                                  f"samples, k {r.detection.k:.3g})")
    lc = r.whole.lcurve
    assert detail["lambda"] == (f"{r.whole.lam:.3g} (L-curve corner, point {lc.corner + 1} of "
                                f"{len(lc.lambdas)})")
    assert detail["grouping"] == r.grouping.mode
    # Quality: the core's figures themselves, before and after.
    assert [q.label for q in rep.quality] == ["static norm error (mg)", "sample norm error (mg)",
                                              "gravity angle (deg)"]
    assert rep.quality[0].figure is r.quality.static_norm_rms_mg
    assert rep.quality[2].figure.after == r.quality.gravity_angle_rms_deg.after
    assert rep.quality[0].figure.before > 10 * rep.quality[0].figure.after  # miscalibrated
    # Parameters: names, units, values and standard errors of each fit, in order.
    (seg,) = rep.segments
    acc, gyro = seg.fits
    assert [p.name for p in acc.params] == list(ACC_PARAM_NAMES)
    assert [p.unit for p in acc.params] == ["rad"] * 3 + ["g/g"] * 3 + ["g"] * 3
    np.testing.assert_array_equal([p.value for p in acc.params], r.segments[0].acc.params)
    np.testing.assert_array_equal([p.std for p in acc.params], r.segments[0].acc.std)
    np.testing.assert_array_equal(acc.values("scale"), r.segments[0].acc.model.K)
    g = r.segments[0].gyro
    assert [p.name for p in gyro.params] == list(GYRO_PARAM_NAMES) + ["b_x", "b_y", "b_z"]
    np.testing.assert_array_equal(gyro.values("bias"), g.model.b)
    assert [p.std for p in gyro.params][9:] == [None] * 3  # measured on the blocks, not fitted
    assert seg.span == (f"{r.segments[0].t_start:.1f}-{r.segments[0].t_end:.1f} s, "
                        f"{r.segments[0].n_blocks} still poses, {r.segments[0].orientations} "
                        "orientations")
    assert f"{len(g.u_meas)} rotations" in gyro.details
    # The units were guessed; one turn tilts gravity under 15 deg (the guide's small turn,
    # now also the warning's: one threshold for both).
    assert [w.code for w in rep.warnings] == ["input", "input", "gyro_rotations_small"]
    assert int(r.guide.turns.small.sum()) == 1


def test_cli_and_viewer_say_the_same(sample):
    rep = report(sample)
    cli = "\n".join(summary_lines(rep, verbose=True))
    md = report_markdown(rep)
    said = [line.text for line in rep.verdict + rep.overview + rep.details]
    said += [q.note for q in rep.quality]
    said += [seg.span for seg in rep.segments] + [f.details for s in rep.segments for f in s.fits]
    said += [w.text for w in rep.warnings] + list(rep.quality_notes)
    for text in said:
        assert text in cli, text
        assert text in md, text
    for q in rep.quality:
        assert f"{fmt(q.figure.after, '.3g'):>10s}" in cli and fmt(q.figure.after, ".4g") in md
    for p in rep.segments[0].fits[0].params:  # the CLI shows misalignments to 3 digits
        assert fmt(p.value, ".3g" if p.kind == "misalignment" else ".6g") in cli
        assert f"| {p.name} ({p.unit}) | {fmt(p.value)} | {fmt(p.std, '.2g')} |" in md


# The thesis's vocabulary: never on the first screen, always behind -v (and in calib.json).
METHOD_TERMS = ("window ", "min length", "Bonferroni", "F-test", "L-curve", "corner",
                "cost reached", "cost ", "M1", "M5", "lambda", "static blocks")


def test_the_first_screen_is_the_verdict_then_plain_words(sample):
    rep = report(sample)
    plain = summary_lines(rep)
    assert plain[0] == f"{'verdict':16s}{sample.verdict.text}"
    assert plain[1] == f"{'next step':16s}{sample.verdict.next_step}"
    assert plain[0] == ("verdict         good: still poses the fit did not see are off by "
                        f"{sample.quality.static_norm_cv_mg:.2g} mg; turns it did not see end "
                        f"{sample.quality.gravity_angle_cv_deg:.2g} deg off the measured gravity")
    for line in plain:
        for term in METHOD_TERMS:
            assert term not in line, (term, line)
    verbose = summary_lines(rep, verbose=True)
    assert set(plain) <= set(verbose)
    shown = "\n".join(verbose)
    for term in ("window ", "Bonferroni", "L-curve corner, point ", "cost reached from each",
                 "lambda "):
        assert term in shown, term
    # The viewer: verdict at the top, the method's terms only in its last section.
    md = report_markdown(rep)
    assert md.splitlines()[2] == f"- **Verdict:** {sample.verdict.text}"
    first, _, last = md.partition("## Method details")
    assert "Bonferroni" in last and "cost reached" in last
    for term in ("Bonferroni", "L-curve", "cost reached", "min length"):
        assert term not in first, term


def test_the_magnetometer_in_a_line_of_the_overview():
    """A session with a magnetometer: its field, the norm's error in and out of sample and the
    directions reached, in the overview the CLI and the viewer print."""
    import imucal
    from imucal.report import report
    from imucal.synth import make_session

    session, truth = make_session(poses=20, seed=4, still=2.0, move=1.5, mag_rate=50.0)
    result = imucal.calibrate(session)
    line = next(x.text for x in report(result).overview if x.label == "magnetometer")
    fit = result.magnetometer
    assert line.startswith(f"{fit.stream}: field {fit.field:.4g}")
    assert abs(fit.field - 0.5) < 0.01  # synth's field, gauss
    assert f"dip {fit.dip_deg:.1f} deg" in line and abs(fit.dip_deg - 65.0) < 0.5
    assert ", rotation from the still blocks and turns;" in line  # M8 and M8t
    assert f"{fit.quality.coverage:.0%} of directions reached" in line
