"""The recording (viewer/): read back with rerun.chunk.RrdReader, headless, no viewer needed.

The screenshot tests of the native and web viewers are in test_viewer_screens.py.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import imucal
from imucal.cli import view_main as main
from imucal.models import ACC_PARAM_NAMES, GYRO_PARAM_NAMES, acc_theta, gyro_theta
from imucal.session import Session
from imucal.synth import make_session
from viewer import paths as P
from viewer import readback as rb
from viewer.app import is_rrd, view, web_command, web_url
from viewer.decimate import envelope
from viewer.recording import DECIMATE_ABOVE, ENVELOPE_ROWS, save_recording, summary_markdown

RERUN = Path(sys.executable).parent / "rerun"


def _record(result, path: Path) -> SimpleNamespace:
    rows = save_recording(result, path)
    return SimpleNamespace(result=result, path=path, rows=rows)


@pytest.fixture(scope="module", params=["sample_data", "synthetic"])
def run(request, tmp_path_factory, sample_session_path) -> SimpleNamespace:
    """sample_data/session.mat through the loader, and a synthetic session whose gyroscope
    runs at another rate than its accelerometer."""
    if request.param == "sample_data":
        session = imucal.load_session(sample_session_path)
    else:
        session, _ = make_session(poses=36, seed=7, gyro_rate=70.0)
    result = imucal.calibrate(session)
    return _record(result, tmp_path_factory.mktemp("rec") / "run.rrd")


def _plotted(rrd, path: str) -> tuple[np.ndarray, np.ndarray, dict]:
    """A 2D plot's series: its points' x and y (as logged: log10 on a log axis) and the values
    stored beside them."""
    v = rb.values(rrd, path)
    xy = np.reshape(np.asarray(v["Points2D:positions"], float), (-1, 2))
    return xy[:, 0], xy[:, 1], v


def _params(rrd, plot: str, names) -> np.ndarray:
    """The y of each named series of a 2D plot, as columns."""
    return np.column_stack([_plotted(rrd, P.series(plot, n))[1] for n in names])


def _still_transitions(result) -> int:
    return sum(s.blocks[1] - s.blocks[0] - 1 for s in result.segments)


def test_every_entity_with_the_rows_logged(run):
    r = run.result
    s = r.session
    n_blocks = len(r.block_times)
    k = _still_transitions(r)
    expected = {
        P.ACC_MAGNITUDE: len(s.t_acc), P.ACC_RAW: len(s.t_acc), P.ACC_CALIBRATED: len(s.t_acc),
        P.GYRO_MAGNITUDE: len(s.t_gyro), P.GYRO_RAW: len(s.t_gyro),
        P.GYRO_CALIBRATED: len(s.t_gyro),
        P.DETECTOR_STATISTIC: len(s.t_acc), P.DETECTOR_THRESHOLD: 2,
        P.DETECTOR_BLOCKS: 2 * n_blocks, P.DETECTOR_SEGMENTS: 2 * len(r.segments),
        P.BLOCK_ERROR_BEFORE: n_blocks, P.BLOCK_ERROR_AFTER: n_blocks,
        P.GRAVITY_MEASURED: n_blocks, P.GRAVITY_PREVIOUS: k, P.GRAVITY_PREDICTED_BEFORE: k,
        P.GRAVITY_PREDICTED_AFTER: k, P.GRAVITY_ANGLE_BEFORE: k, P.GRAVITY_ANGLE_AFTER: k,
    }
    in_file = rb.entities(run.path)
    for path, n in expected.items():
        assert in_file.get(path) == n, path
    # What log_result reports having sent is what the file holds, entity by entity.
    assert {p: n for p, n in in_file.items() if n} == run.rows
    for static in (P.SUMMARY, P.INFO, P.QUALITY, P.calibration(1, "accelerometer"),
                   P.calibration(1, "gyroscope"), P.LCURVE_POINTS, P.LCURVE_CORNER,
                   P.LAMBDA_STATIC_RMS, P.LAMBDA_STATIC_MAX, P.LAMBDA_CHOSEN,
                   P.series(P.LAMBDA_SCALE, "s_x"),
                   P.iteration_series("segment_1", "accelerometer", "log10_cost", "cost"),
                   P.iteration_series("segment_1", "gyroscope", "bias", "b_z"), P.GRAVITY_AXES):
        assert in_file.get(static) == 0, static  # static: drawn whatever the timeline


def test_signals_are_the_sessions_own(run):
    r, s = run.result, run.result.session
    t, mag = rb.scalars(run.path, P.ACC_MAGNITUDE)
    np.testing.assert_allclose(t, s.t_acc, atol=2e-9, rtol=0)
    np.testing.assert_array_equal(mag[:, 1], r.calibrated.acc_norm)
    np.testing.assert_allclose(mag[:, 0], np.linalg.norm(s.acc, axis=1), rtol=1e-12)  # in g
    t, w = rb.scalars(run.path, P.GYRO_MAGNITUDE)
    np.testing.assert_allclose(t, s.t_gyro, atol=2e-9, rtol=0)
    np.testing.assert_array_equal(w[:, 1], r.calibrated.gyro_norm)
    t, axes = rb.scalars(run.path, P.ACC_CALIBRATED)  # short: not decimated
    np.testing.assert_array_equal(axes, r.calibrated.acc)
    t, stat = rb.scalars(run.path, P.DETECTOR_STATISTIC)
    np.testing.assert_allclose(stat, np.log10(r.detection.statistic(s.acc)), rtol=1e-12)
    _, thr = rb.scalars(run.path, P.DETECTOR_THRESHOLD)
    np.testing.assert_allclose(thr, np.log10(r.detection.threshold))


def test_calibrated_still_magnitude_within_1_mg_of_g(run):
    """From the file alone: the still blocks' lanes and the calibrated magnitude."""
    t_state, states = rb.column(run.path, P.DETECTOR_BLOCKS, "StateChange:state")
    starts = t_state[[s == ["still"] for s in states]]
    ends = t_state[[s == [""] for s in states]]
    assert len(starts) == len(ends) == len(run.result.block_times)
    t, mag = rb.scalars(run.path, P.ACC_MAGNITUDE)
    g = rb.values(run.path, P.INFO)["g"]
    errors = []
    for a, b in zip(starts, ends):
        inside = (t >= a) & (t <= b)
        errors.append((mag[inside, 1].mean() / g - 1) * 1e3)
    assert np.max(np.abs(errors)) < 1.0, errors
    # and the raw still magnitude is visibly off (the sample is miscalibrated on purpose)
    raw = [(mag[(t >= a) & (t <= b), 0].mean() / g - 1) * 1e3 for a, b in zip(starts, ends)]
    assert np.sqrt(np.mean(np.square(raw))) > 5.0


def test_lcurve_corner_is_the_chosen_lambda(run, tmp_path):
    r = run.result
    imucal.save_calibration(r, tmp_path / "calib.json")
    saved = json.loads((tmp_path / "calib.json").read_text())["lambda"]
    corner = rb.values(run.path, P.LCURVE_CORNER)
    assert corner["lambda"] == r.whole.lam == saved
    assert rb.values(run.path, P.INFO)["lambda"] == saved
    lc = r.whole.lcurve
    assert corner["index"] == lc.corner
    xy = corner["Points2D:positions"]
    np.testing.assert_allclose(xy, [np.log10(lc.residual_norm[lc.corner]),
                                    np.log10(lc.solution_norm[lc.corner])], rtol=1e-6)
    points = rb.values(run.path, P.LCURVE_POINTS)
    np.testing.assert_array_equal(points["lambda"], lc.lambdas)
    assert len(points["Points2D:positions"]) == len(points["Points2D:labels"]) == len(lc.lambdas)
    assert any(lab.startswith("λ=") for lab in points["Points2D:labels"])


def test_lambda_sweep_agrees_with_the_calibration(run):
    r = run.result
    lc = r.whole.lcurve
    x, y, v = _plotted(run.path, P.LAMBDA_STATIC_RMS)
    np.testing.assert_array_equal(v["lambda"], lc.lambdas)
    np.testing.assert_allclose(x, np.log10(lc.lambdas), rtol=1e-6)  # float32 positions
    rms = np.asarray(v["mg"])
    np.testing.assert_allclose(y, np.log10(rms), rtol=1e-5, atol=1e-6)
    # At the corner the sweep's parameters are the calibration's: same block errors, same K.
    expected = np.sqrt(np.mean(np.square(r.quality.block_norm_error_mg)))
    assert rms[lc.corner] == pytest.approx(expected, rel=1e-6, abs=1e-9)
    chosen = rb.values(run.path, P.LAMBDA_CHOSEN)
    assert chosen["lambda"] == lc.lambdas[lc.corner] and chosen["mg"] == rms[lc.corner]
    scale = _params(run.path, P.LAMBDA_SCALE, ("s_x", "s_y", "s_z"))
    np.testing.assert_allclose(scale[lc.corner], r.whole.model.K, rtol=1e-6)


def test_iteration_traces_end_at_the_solution(run):
    r = run.result
    acc, gyro = r.segments[0].acc, r.segments[0].gyro
    x, y, v = _plotted(run.path, P.iteration_series("segment_1", "accelerometer", "log10_cost",
                                                    "cost"))
    np.testing.assert_array_equal(x, np.arange(len(acc.report.trace_cost)))
    np.testing.assert_array_equal(v["step"], x)
    np.testing.assert_array_equal(v["cost"], acc.report.trace_cost)
    assert v["cost"][-1] == pytest.approx(acc.report.cost, rel=1e-12)
    np.testing.assert_allclose(y, np.log10(acc.report.trace_cost), rtol=1e-6)
    plot = P.iteration("accelerometer", "scale")
    np.testing.assert_allclose(_params(run.path, plot,
                                       [f"segment_1/{n}" for n in ("s_x", "s_y", "s_z")])[-1],
                               acc.model.K, rtol=1e-6)  # float32 positions
    gscale = _params(run.path, P.iteration("gyroscope", "scale"),
                     [f"segment_1/{n}" for n in GYRO_PARAM_NAMES[6:9]])
    np.testing.assert_allclose(gscale[-1], gyro.model.K, rtol=1e-6)
    gmis = _params(run.path, P.iteration("gyroscope", "misalignment"),
                   [f"segment_1/{n}" for n in GYRO_PARAM_NAMES[0:6]])
    np.testing.assert_allclose(gmis[-1], gyro_theta(gyro.model)[:6], atol=1e-7)


def test_parameters_and_quality_as_plain_values(run):
    r = run.result
    seg = r.segments[0]
    acc = rb.values(run.path, P.calibration(1, "accelerometer"))
    np.testing.assert_array_equal(np.reshape(acc["T"], (3, 3)), seg.acc.model.T)
    np.testing.assert_array_equal(acc["K"], seg.acc.model.K)
    np.testing.assert_array_equal(acc["b"], seg.acc.model.b)
    np.testing.assert_array_equal(acc["params"], acc_theta(seg.acc.model))
    np.testing.assert_array_equal(acc["std"], seg.acc.std)
    assert acc["param_names"][3] == "s_x" and acc["lambda"] == seg.acc.lam
    gyro = rb.values(run.path, P.calibration(1, "gyroscope"))
    np.testing.assert_array_equal(np.reshape(gyro["T"], (3, 3)), seg.gyro.model.T)
    np.testing.assert_array_equal(gyro["b"], seg.gyro.model.b)
    q = rb.values(run.path, P.QUALITY)
    assert q["static_norm_rms_mg_after"] == r.quality.static_norm_rms_mg.after
    assert q["static_norm_rms_mg_before"] == r.quality.static_norm_rms_mg.before
    assert q["gravity_angle_rms_deg_after"] == r.quality.gravity_angle_rms_deg.after
    np.testing.assert_array_equal(q["block_norm_error_mg"], r.quality.block_norm_error_mg)
    info = rb.values(run.path, P.INFO)
    assert info["n_warnings"] == len(r.warnings)
    if r.warnings:
        # one warning reads back as a bare string (an array of one)
        assert list(np.atleast_1d(info["warnings"])) == [w.text for w in r.warnings]


def test_summary_is_a_markdown_table(run):
    r = run.result
    doc = rb.values(run.path, P.SUMMARY)
    text = doc["TextDocument:text"]
    assert text == summary_markdown(r)
    assert doc["TextDocument:media_type"] == "text/markdown"
    assert "| s_x (g/g) |" in text and "| b_z (rad/s) |" in text
    assert f"{r.quality.static_norm_rms_mg.after:.4g}" in text
    for w in r.warnings:
        assert w.text in text


def test_gravity_arrows_follow_the_blocks(run):
    r = run.result
    fit = r.segments[0].gyro
    def unit(v):
        v = np.asarray(v, float).reshape(-1, 3)
        return v / np.linalg.norm(v, axis=1, keepdims=True)

    t, measured = rb.column(run.path, P.GRAVITY_MEASURED, "Arrows3D:vectors")
    np.testing.assert_allclose(t, r.block_times[:, 0], atol=2e-9)
    np.testing.assert_allclose(unit(measured), np.vstack([fit.u_prev[:1], fit.u_meas]),
                               atol=1e-6)  # float32 in the file
    t, after = rb.column(run.path, P.GRAVITY_PREDICTED_AFTER, "Arrows3D:vectors")
    np.testing.assert_allclose(t, r.block_times[1:, 0], atol=2e-9)
    np.testing.assert_allclose(unit(after), fit.u_pred_after, atol=1e-6)
    _, before = rb.column(run.path, P.GRAVITY_PREDICTED_BEFORE, "Arrows3D:vectors")
    np.testing.assert_allclose(unit(before), fit.u_pred_before, atol=1e-6)
    _, angle = rb.scalars(run.path, P.GRAVITY_ANGLE_AFTER)
    np.testing.assert_allclose(angle, fit.angle_after)
    _, before = rb.scalars(run.path, P.GRAVITY_ANGLE_BEFORE)
    assert np.sqrt(np.mean(before**2)) > 10 * np.sqrt(np.mean(angle**2))


def test_rows_read_back_are_the_cores_arrays(run):
    """Every plotted number is the core's own: the viewer reshapes, it does not compute."""
    r = run.result
    t, mag = rb.scalars(run.path, P.ACC_MAGNITUDE)
    np.testing.assert_array_equal(mag, np.column_stack([r.raw_acc_norm, r.calibrated.acc_norm]))
    _, w = rb.scalars(run.path, P.GYRO_MAGNITUDE)
    np.testing.assert_array_equal(w, np.column_stack([r.raw_gyro_norm, r.calibrated.gyro_norm]))
    t, after = rb.scalars(run.path, P.BLOCK_ERROR_AFTER)
    np.testing.assert_allclose(t, r.block_middles, atol=2e-9, rtol=0)
    np.testing.assert_array_equal(after, r.quality.block_norm_error_mg)
    _, before = rb.scalars(run.path, P.BLOCK_ERROR_BEFORE)
    np.testing.assert_array_equal(before, r.quality.block_norm_error_before_mg)

    sweep = r.whole.sweep
    for path, expected in ((P.LAMBDA_STATIC_RMS, sweep.static_norm_rms_mg),
                           (P.LAMBDA_STATIC_MAX, sweep.static_norm_max_mg)):
        np.testing.assert_array_equal(rb.values(run.path, path)["mg"], expected, err_msg=path)
    for plot, cols in ((P.LAMBDA_MISALIGNMENT, slice(0, 3)), (P.LAMBDA_SCALE, slice(3, 6)),
                       (P.LAMBDA_BIAS, slice(6, 9))):
        np.testing.assert_allclose(_params(run.path, plot, ACC_PARAM_NAMES[cols]),
                                   sweep.params[:, cols], rtol=1e-6, atol=1e-9, err_msg=plot)

    acc, gyro = r.segments[0].acc, r.segments[0].gyro
    for sensor, what, names, expected in (
            ("accelerometer", "misalignment", ACC_PARAM_NAMES[0:3], acc.trace_params[:, 0:3]),
            ("accelerometer", "scale", ACC_PARAM_NAMES[3:6], acc.trace_params[:, 3:6]),
            ("accelerometer", "bias", ACC_PARAM_NAMES[6:9], acc.trace_params[:, 6:9]),
            ("gyroscope", "misalignment", GYRO_PARAM_NAMES[0:6], gyro.trace_params[:, 0:6]),
            ("gyroscope", "scale", GYRO_PARAM_NAMES[6:9], gyro.trace_params[:, 6:9]),
            ("gyroscope", "bias", ("b_x", "b_y", "b_z"), gyro.trace_bias)):
        v = _params(run.path, P.iteration(sensor, what), [f"segment_1/{n}" for n in names])
        np.testing.assert_allclose(v, expected, rtol=1e-6, atol=1e-9,  # float32 positions
                                   err_msg=f"{sensor} {what}")

    _, measured = rb.column(run.path, P.GRAVITY_MEASURED, "Arrows3D:vectors")
    np.testing.assert_allclose(np.reshape(measured, (-1, 3)), gyro.u_blocks, atol=1e-6)
    _, angle = rb.scalars(run.path, P.GRAVITY_ANGLE_BEFORE)
    np.testing.assert_array_equal(angle, gyro.angle_before)

    info = rb.values(run.path, P.INFO)
    codes = [w.code for w in r.warnings] or [""]
    assert (info["warning_codes"] if isinstance(info["warning_codes"], list)
            else [info["warning_codes"]]) == codes


def test_blueprint_is_stored_with_every_kind_of_view(run):
    views = rb.blueprint_views(run.path)
    classes = {c for c, _ in views}
    assert {"TimeSeries", "StateTimeline", "3D", "2D", "TextDocument"} <= classes
    names = [n for _, n in views]
    assert any("vs λ" in n for n in names) and any("accepted step" in n for n in names)
    assert rb.blueprint_containers(run.path) == sorted(
        ["Overview", "Signals", "Gravity", "L-curve", "Optimiser"])


@pytest.mark.skipif(not RERUN.exists(), reason="the rerun executable is not in the venv")
def test_rrd_verify(run):
    out = subprocess.run([str(RERUN), "rrd", "verify", str(run.path)], capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 0, out.stderr


def test_envelope_keeps_every_peak():
    rng = np.random.default_rng(1)
    n = 1_000_003
    t = np.arange(n) / 1000.0
    x = rng.normal(size=(n, 3))
    x[123_457, 1] = 50.0
    x[999_999, 2] = -60.0
    te, xe = envelope(t, x, 10_000)
    assert len(te) == len(xe) <= 10_000
    np.testing.assert_array_equal(xe.max(axis=0), x.max(axis=0))
    np.testing.assert_array_equal(xe.min(axis=0), x.min(axis=0))
    assert np.all(np.diff(te) >= 0) and te[0] == t[0] and te[-1] <= t[-1]
    # the spike is drawn within one bucket of where it happened
    bucket = -(-n // 5_000) / 1000.0
    assert abs(te[np.argmax(xe[:, 1])] - t[123_457]) <= bucket
    t1, x1 = envelope(t[:50], x[:50, 0], 100)  # short: unchanged
    assert t1 is t[:50].base or np.array_equal(t1, t[:50])
    np.testing.assert_array_equal(x1, x[:50, 0])


def test_long_session_magnitudes_full_rate_when_still_envelope_between(tmp_path):
    s, _ = make_session(poses=50, seed=3, acc_rate=1000.0, gyro_rate=140.0)
    assert len(s.t_acc) > DECIMATE_ABOVE
    r = imucal.calibrate(s)
    path = tmp_path / "long.rrd"
    rows = save_recording(r, path)
    assert rows[P.ACC_RAW] <= ENVELOPE_ROWS and rows[P.DETECTOR_STATISTIC] <= ENVELOPE_ROWS
    _, raw = rb.scalars(path, P.ACC_RAW)
    np.testing.assert_array_equal(raw.max(axis=0), s.acc.max(axis=0))
    np.testing.assert_array_equal(raw.min(axis=0), s.acc.min(axis=0))

    still = np.zeros(len(s.t_acc), bool)
    for a, b in r.detection.blocks:
        still[a:b] = True
    t, v = rb.scalars(path, P.ACC_MAGNITUDE)
    assert rows[P.ACC_MAGNITUDE] == len(t) < len(s.t_acc)
    assert np.all(np.diff(t) >= 0)
    bt = r.block_times  # [first, last] sample time of each block
    k = np.clip(np.searchsorted(bt[:, 0], t + 1e-7, side="right") - 1, 0, len(bt) - 1)
    in_block = (t >= bt[k, 0] - 1e-7) & (t <= bt[k, 1] + 1e-7)
    # Every still sample at full rate, exactly; nothing else inside a still block.
    assert in_block.sum() == still.sum()
    np.testing.assert_array_equal(v[in_block, 1], r.calibrated.acc_norm[still])
    # Between the blocks a min/max envelope: far fewer rows, every peak kept.
    moving = r.calibrated.acc_norm[~still]
    assert (~in_block).sum() <= ENVELOPE_ROWS < (~still).sum()
    assert v[~in_block, 1].max() == moving.max() and v[~in_block, 1].min() == moving.min()
    raw_moving = np.linalg.norm(r.whole.nominal.to_nominal(s.acc[~still]), axis=1)
    np.testing.assert_allclose(v[~in_block, 0].max(), raw_moving.max() * r.whole.g_out,
                               rtol=1e-12)
    tg, vg = rb.scalars(path, P.GYRO_MAGNITUDE)
    assert len(tg) == rows[P.GYRO_MAGNITUDE] and len(tg) <= len(s.t_gyro)
    assert vg[:, 1].max() == r.calibrated.gyro_norm.max()
    # The gyroscope's still samples (the core's mask, the bias's samples) at full rate.
    t_still = s.t_gyro[r.gyro_still]
    k = np.clip(np.searchsorted(tg, t_still - 1e-7), 0, len(tg) - 1)
    np.testing.assert_allclose(tg[k], t_still, atol=1e-7, rtol=0)
    np.testing.assert_array_equal(vg[k], np.column_stack(
        [r.raw_gyro_norm, r.calibrated.gyro_norm])[r.gyro_still])
    # Size model: ~28 bytes per full-rate magnitude row plus envelopes that do not grow
    # with the session: a long recording is mostly motion and stays small.
    kg = np.searchsorted(bt[:, 0], s.t_gyro, side="right") - 1
    n_gyro_still = np.count_nonzero((kg >= 0) & (s.t_gyro <= bt[np.maximum(kg, 0), 1]))
    assert path.stat().st_size < 30 * (still.sum() + n_gyro_still) + 25e6


def test_two_segments_accelerometer_only_and_raw_counts(tmp_path):
    s, _ = make_session(poses=40, seed=5, change_at=0.5)
    r = imucal.calibrate(s)
    assert len(r.segments) == 2
    rec = _record(r, tmp_path / "two.rrd")
    ents = rb.entities(rec.path)
    # Segments numbered from 1 in the recording too, as the CLI prints them.
    for p in (P.lcurve_segment(1) + "_corner", P.lcurve_segment(2),
              P.iteration_series("whole", "accelerometer", "scale", "s_x"),
              P.iteration_series("segment_2", "gyroscope", "scale", "s_z"),
              P.calibration(2, "gyroscope")):
        assert p in ents, p
    _, states = rb.column(rec.path, P.DETECTOR_SEGMENTS, "StateChange:state")
    assert [s[0] for s in states] == ["segment 1", "between segments", "segment 2", ""]
    assert P.lcurve_segment(0) not in ents and P.calibration(0, "gyroscope") not in ents

    acc_only = Session(acc=s.acc, t_acc=s.t_acc, acc_unit="g")
    r = imucal.calibrate(acc_only, lam=0.01, single_segment=True)
    rec = _record(r, tmp_path / "acc.rrd")
    ents = rb.entities(rec.path)
    assert P.ACC_MAGNITUDE in ents and P.BLOCK_ERROR_AFTER in ents
    assert not any(p.startswith(("imu/gyroscope", "gravity", "lcurve", "lambda")) for p in ents)
    assert "L-curve" not in rb.blueprint_containers(rec.path)
    assert rb.values(rec.path, P.INFO)["lambda"] == 0.01

    counts, _ = make_session(poses=30, seed=2, acc_unit="counts", gyro_unit="counts")
    r = imucal.calibrate(counts)
    rec = _record(r, tmp_path / "counts.rrd")
    _, mag = rb.scalars(rec.path, P.ACC_MAGNITUDE)
    _, w = rb.scalars(rec.path, P.GYRO_MAGNITUDE)
    # "raw" goes through the nominal frame: comparable with the calibrated magnitude
    assert np.median(mag[:, 0] / mag[:, 1]) == pytest.approx(1.0, abs=0.1)
    assert w[:, 0].max() == pytest.approx(w[:, 1].max(), rel=0.1)


def test_save_is_atomic(tmp_path, monkeypatch, run):
    target = tmp_path / "keep.rrd"
    target.write_bytes(b"previous")
    import viewer.recording as recording

    def boom(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(recording, "log_result", boom)
    with pytest.raises(KeyboardInterrupt):
        save_recording(run.result, target)
    assert target.read_bytes() == b"previous"
    assert [p.name for p in tmp_path.iterdir()] == ["keep.rrd"]
    with pytest.raises(imucal.ImucalError):
        save_recording(run.result, tmp_path / "missing" / "x.rrd")


# --- imucal-view ---------------------------------------------------------------------------------


def test_view_save_writes_a_recording_and_opens_nothing(tmp_path, sample_session_path, capsys):
    out = tmp_path / "run.rrd"
    assert view(str(sample_session_path), save=str(out)) == 0
    assert is_rrd(out) and out.read_bytes()[:3] == b"RRF"
    assert capsys.readouterr().out.strip() == f"wrote {out}"
    copy = tmp_path / "copy"
    assert view(str(out), save=str(copy)) == 0  # an .rrd is copied as it is
    assert copy.read_bytes() == out.read_bytes() and is_rrd(copy)


def test_view_without_display_saves_beside_the_cwd(tmp_path, sample_session_path, capsys,
                                                  monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.chdir(tmp_path)
    assert view(str(sample_session_path)) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1 and "no display" in out[0]
    assert is_rrd(tmp_path / "session.rrd")
    assert view(str(tmp_path / "session.rrd")) == 1  # an .rrd cannot be shown: one line
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no display" in err[0]


def test_view_errors_are_one_line(tmp_path, capsys):
    assert view(str(tmp_path / "nothing.mat"), save=str(tmp_path / "x.rrd")) == 1
    bad = tmp_path / "bad.csv"
    bad.write_text("not, numbers\nat, all\n")
    assert view(str(bad), save=str(tmp_path / "x.rrd")) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(e.startswith("imucal-view: ") for e in err)
    assert not (tmp_path / "x.rrd").exists()


def test_cli_main(tmp_path, sample_session_path):
    out = tmp_path / "cli.rrd"
    with pytest.raises(SystemExit) as e:
        main([str(sample_session_path), "--save", str(out)])
    assert e.value.code == 0 and is_rrd(out)
    with pytest.raises(SystemExit) as e:
        main([str(tmp_path / "missing.mat"), "--save", str(out)])
    assert e.value.code == 1


def test_imucal_view_takes_every_option_of_imucal_view(tmp_path, sample_session_path, capsys):
    """``imucal-view`` is ``imucal view``: a two-file text session (imu_tk's layout) with a
    setting, then a bad option value and a missing file, each one line and its exit code."""
    from scipy.io import loadmat

    data = loadmat(sample_session_path)
    for sensor in ("acc", "gyro"):
        np.savetxt(tmp_path / f"{sensor}.txt",
                   np.hstack([data[f"t_{sensor}"].reshape(-1, 1), data[sensor]]), fmt="%.9g")
    out = tmp_path / "two.rrd"
    with pytest.raises(SystemExit) as e:
        main([str(tmp_path / "acc.txt"), "--gyro", str(tmp_path / "gyro.txt"), "--lambda",
              "0.01", "--save", str(out)])
    assert e.value.code == 0 and is_rrd(out)
    assert rb.values(out, P.INFO)["lambda"] == pytest.approx(0.01)
    capsys.readouterr()
    with pytest.raises(SystemExit) as e:
        main([str(tmp_path / "acc.txt"), "--k", "-1", "--save", str(out)])
    assert e.value.code == 2
    with pytest.raises(SystemExit) as e:
        main([str(tmp_path / "missing.txt"), "--save", str(tmp_path / "x.rrd")])
    assert e.value.code == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == f"imucal-view: error: {tmp_path / 'missing.txt'}: file not found"
    assert not (tmp_path / "x.rrd").exists()


def test_web_command_binds_loopback():
    cmd = web_command("rerun", "x.rrd", 9090, 9876)
    assert cmd[cmd.index("--bind") + 1] == "127.0.0.1"
    assert "--web-viewer-port" in cmd and "9090" in cmd and "--port" in cmd
    assert web_url(9090, 9876) == ("http://127.0.0.1:9090/?url="
                                   "rerun%2Bhttp%3A%2F%2F127.0.0.1%3A9876%2Fproxy")


def test_core_and_cli_do_not_load_rerun():
    core = Path(imucal.__file__).parent
    for f in core.glob("*.py"):
        text = f.read_text()
        assert "import rerun" not in text and "from viewer" not in text, f.name
    code = ("import imucal, sys, viewer.app, viewer.paths; imucal.calibrate; "
            "print('rerun' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=dict(os.environ), timeout=60)
    assert out.stdout.strip() == "False"
