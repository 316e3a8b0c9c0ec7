"""What a live capture keeps for its running fits does not grow with the stream (issue 25:
constant memory apart from the session file), the running fit on it agrees with the full method
on the whole session, and a spec that can no longer be met stops the capture failed, naming
the limit (method.md §13)."""

import os
import threading

import numpy as np
import pytest

import imucal
from imucal.capture.detector import StillDetector
from imucal.capture.run import capture
from imucal.capture.running import fit_retained, retained
from imucal.capture.send import frames_of, paced
from imucal.capture.sources import FdSource
from imucal.capture.stop import PRESETS, lost_limits, progress, running_progress
from imucal.capture.turns import TurnBuffer
from imucal.cli.capture import spec_check
from imucal.models import SensorModel, acc_theta, gyro_theta
from imucal.synth import make_session

NAMES, ACC, GYRO = ["t", "ax", "ay", "az", "gx", "gy", "gz"], [1, 2, 3], [4, 5, 6]


def _feed(det: StillDetector, session, start: int, stop: int, batch: int = 37) -> None:
    t, a, g = session.t_acc, session.acc, session.gyro
    for i in range(start, stop, batch):
        j = min(i + batch, stop)
        det.feed(t[i:j], a[i:j], g[i:j])


def test_retained_state_does_not_grow_with_the_stream():
    # 100 poses; small caps so that N samples already fill them: 4N must keep no more.
    session, _ = make_session(poses=100, seed=5)
    n = len(session.t_acc) // 4
    det = StillDetector(max_blocks=8, max_turns=4)
    _feed(det, session, 0, n)
    at_n = det.retained()
    _feed(det, session, n, 4 * n)
    at_4n = det.retained()
    assert det.n_holds > 3 * 20  # the stream had far more holds than are kept
    assert at_n["blocks"] == at_4n["blocks"] == 8
    assert at_n["turns"] == at_4n["turns"] == 4 and at_4n["chain"] == 5
    # each turn of 2 s at 100 Hz, plus its ends: rows and bytes as at N, within one turn's
    assert at_4n["turn_rows"] < 4 * 400 and abs(at_4n["turn_rows"] - at_n["turn_rows"]) < 400
    assert at_4n["bytes"] < 1.5 * at_n["bytes"]


def test_a_long_turn_keeps_bounded_rows_and_its_rotation():
    # 59 s of turning at 1 kHz (59 000 samples, from rest to rest as between two holds) into
    # 256 rows; the integral of the rate over the rows (what M5 turns gravity with) is the
    # samples' within 1e-4: each row is the mean of its samples at their mean time.
    t = np.arange(60_000) / 1000.0
    env = np.sin(np.pi * np.clip(t / 59.0, 0, 1)) ** 2
    w = env[:, None] * np.column_stack([np.sin(0.5 * t), np.cos(0.3 * t),
                                        0.2 + 0.1 * np.sin(2 * t)])
    rows = np.column_stack([t, w])
    buf = TurnBuffer(rows[:2], cap=256)
    rng = np.random.default_rng(0)
    i = 2
    while i < 59_000:
        j = min(i + int(rng.integers(1, 700)), 59_000)
        buf.add(rows[i:j])
        i = j
    assert buf.n <= 256 and buf.factor >= 128
    out = buf.finish(t[59_000], rows[59_000:59_002])
    assert len(out) <= 256 + 5 and np.all(np.diff(out[:, 0]) > 0)
    whole = np.trapezoid(w[:59_002], t[:59_002], axis=0)
    kept = np.trapezoid(out[:, 1:], out[:, 0], axis=0)
    assert np.allclose(kept, whole, rtol=1e-4, atol=1e-3), (kept, whole)


def test_running_fit_agrees_with_the_full_method():
    session, truth = make_session(poses=30, seed=3)
    det = StillDetector()
    _feed(det, session, 0, len(session.t_acc))
    fit = fit_retained(retained(det, NAMES, ACC, GYRO))
    seg = imucal.calibrate(session).segments[0]
    # accelerometer: the same parameters within a standard error (the holds are not the
    # batch detector's blocks: their ends, and so their noise, differ)
    za = (acc_theta(fit.acc.model) - acc_theta(seg.acc.model)) / seg.acc.std
    assert np.abs(za).max() < 1.0, za
    assert np.allclose(fit.acc.std, seg.acc.std, rtol=0.15)
    # gyroscope: from the kept turns only, within a standard error, errors within 25 %
    zg = (gyro_theta(fit.gyro.model) - gyro_theta(seg.gyro.model)) / seg.gyro.std[:9]
    assert np.abs(zg).max() < 1.0, zg
    assert np.allclose(fit.gyro.std[:9], seg.gyro.std[:9], rtol=0.25)
    live = running_progress(fit, PRESETS["default"])
    assert live.level == "good" and live.met
    assert live.ratio == pytest.approx(progress(imucal.calibrate(session),
                                                PRESETS["default"]).ratio, rel=0.25)


def test_lost_limits_rule():
    spec = {"acc_bias_mg": 40.0, "static_norm_error_mg": 1.0, "acc_scale_pct": 1.0}
    row = {"acc_unit_raw": "g", "acc_b_x": 0.050, "acc_std_b_x": 0.001,  # 10 sd past 40 mg
           "acc_b_y": 0.043, "acc_std_b_y": 0.001,  # 3 sd past: more data may bring it in
           "acc_b_z": 0.0, "acc_std_b_z": 0.001, "acc_s_x": 1.02, "acc_std_s_x": np.nan,
           "static_norm_floor_mg": 0.4}
    lost = lost_limits(spec, row)
    assert len(lost) == 1 and lost[0].startswith("acc_bias_mg: b_x = 50 mg, 10 standard")
    assert lost_limits(spec, row | {"static_norm_floor_mg": 1.2})[-1].startswith(
        "static_norm_error_mg: the still poses scatter by at least 1.2 mg")
    # a raw unit the limit cannot read (counts) is never lost early
    assert lost_limits(spec, row | {"acc_unit_raw": "counts"}) == []


def test_spec_that_can_no_longer_pass_stops_failed(tmp_path):
    # A device whose accelerometer bias on x is 80 mg, against a limit of 40 mg.
    acc = SensorModel(T=np.eye(3), K=np.array([1.01, 0.99, 1.0]), b=np.array([0.08, 0.0, 0.0]))
    session, _ = make_session(poses=60, seed=4, acc_truth=acc)  # 305 s, sent in 15 s
    head, frames = frames_of(session, "lines")
    r, w = os.pipe()

    def device() -> None:
        with os.fdopen(w, "wb", buffering=0) as f:
            try:
                f.write(b"".join(head))
                paced(session.t_acc, frames, 20.0, lambda chunk: f.write(b"".join(chunk)))
            except BrokenPipeError:
                pass

    thread = threading.Thread(target=device, daemon=True)
    thread.start()
    limits = tmp_path / "limits.toml"
    limits.write_text("acc_bias_mg = 40\nacc_scale_pct = 5\n")
    spec = spec_check(limits)
    report = capture(FdSource(r), tmp_path / "D", PRESETS["factory"], spec=spec, until=60)
    os.close(r)
    thread.join()
    assert report.stopped.startswith("out of the spec: acc_bias_mg: b_x = 8"), report.stopped
    assert "standard errors past the limit 40" in report.stopped
    assert not report.passed and report.final.broken  # the whole file breaks it too
    assert report.samples < 0.6 * len(session.t_acc)  # long before the stream's end
