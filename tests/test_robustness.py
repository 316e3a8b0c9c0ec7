"""Never a traceback, never a silent wrong answer (core side): property tests on the pipeline,
determinism, and atomic outputs surviving a kill."""

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import imucal
from imucal.session import Session
from imucal.synth import make_session


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    acc=arrays(np.float64, st.tuples(st.integers(0, 400), st.integers(1, 4)),
               elements=st.floats(allow_nan=True, allow_infinity=True, width=64)),
    order=st.sampled_from(["increasing", "shuffled", "constant", "duplicated"]),
    rate=st.floats(1.0, 2000.0),
)
def test_pipeline_raises_only_its_own_error(acc, order, rate):
    n = len(acc)
    t = np.arange(n) / rate
    rng = np.random.default_rng(n)
    if order == "shuffled":
        t = rng.permutation(t)
    elif order == "constant":
        t = np.zeros(n)
    elif order == "duplicated" and n > 2:
        t[n // 2] = t[n // 2 - 1]
    session = Session(acc=acc, t_acc=t)
    try:
        imucal.calibrate(session)
    except imucal.ImucalError as e:
        assert "\n" not in str(e)


@settings(max_examples=25, deadline=None)
@given(noise=st.floats(1e-6, 0.2), poses=st.integers(2, 14), nan_at=st.integers(-1, 2000))
def test_detector_on_odd_sessions(noise, poses, nan_at):
    session, _ = make_session(poses=poses, seed=poses, acc_noise=noise, still=1.5, move=1.0)
    acc = session.acc.copy()
    if 0 <= nan_at < len(acc):
        acc[nan_at] = np.nan
    try:
        r = imucal.calibrate(Session(acc=acc, t_acc=session.t_acc, gyro=session.gyro,
                                     t_gyro=session.t_gyro))
    except imucal.ImucalError as e:
        assert "\n" not in str(e)
    else:
        assert np.isfinite(r.quality.static_norm_rms_mg.after)


def test_all_static_and_no_static():
    t = np.arange(3000) / 100.0
    still = np.tile([0.0, 0.0, 1.0], (3000, 1)) + np.random.default_rng(0).normal(0, 1e-3,
                                                                                    (3000, 3))
    for acc, word in ((still, "nearly every sample looks still"),):
        try:
            imucal.calibrate(Session(acc=acc, t_acc=t))
        except imucal.ImucalError as e:
            assert "found 1 static block of" in str(e) and word in str(e)
        else:
            raise AssertionError("an all-still session must be refused")
    moving = still.copy()
    moving[300:] += np.random.default_rng(1).normal(0, 0.5, (2700, 3))
    try:
        imucal.calibrate(Session(acc=moving, t_acc=t))
    except imucal.ImucalError as e:
        assert "static blocks" in str(e) and "few samples look still" in str(e)
    else:
        raise AssertionError("a session with no still pose must be refused")


def test_byte_identical_calibration_files(tmp_path):
    session, _ = make_session(poses=20, seed=3)
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    imucal.save_calibration(imucal.calibrate(session), a)
    imucal.save_calibration(imucal.calibrate(session), b)
    assert a.read_bytes() == b.read_bytes()
    assert json.loads(a.read_text())["format"] == "imucal-calibration"


WRITER = """
import sys, numpy as np
from imucal.io.atomic import write_text_atomic
i = 0
while True:
    i += 1
    write_text_atomic(sys.argv[1], ("%d\\n" % i) * 2_000_000 + "end\\n")
"""


def test_killed_mid_write_leaves_previous_output_intact(tmp_path):
    target = tmp_path / "out.txt"
    target.write_text("previous\n")
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(target)])
    try:
        for delay in (0.3, 0.45, 0.6, 0.8):
            time.sleep(delay)
            os.kill(proc.pid, signal.SIGSTOP)  # freeze it mid-way, then read the target
            text = target.read_text()
            assert text == "previous\n" or text.endswith("end\n")
            os.kill(proc.pid, signal.SIGCONT)
    finally:
        proc.kill()
        proc.wait()
    text = target.read_text()
    assert text == "previous\n" or (text.endswith("end\n") and len(text.splitlines()) == 2_000_001)
