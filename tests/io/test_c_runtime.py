"""``imucal export --to c-runtime`` (issue 26 item 3): the C99 runtime compiled with the system
compiler and run on synthetic everyday use with a drifted gyroscope bias and accelerometer bias
and scale (imucal.inuse.everyday), against the Python's apply, still moments (method.md §10) and
refresh (M10, M11), and against the truth."""

from __future__ import annotations

import dataclasses
import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from imucal.cli.main import main
from imucal.inuse.check import Stored
from imucal.inuse.estimate import fit_acc
from imucal.inuse.everyday import Drift, make_everyday
from imucal.inuse.refresh import refresh
from imucal.io.exports import c_runtime
from imucal.io.exports.common import ExportInput
from imucal.stages.apply import Calibration, SegmentModels

CC = shutil.which("cc")
pytestmark = pytest.mark.skipif(CC is None, reason="no system C compiler (cc) on this machine")

DENSITY = 0.003 / 10.0  # the synthetic sensor's white noise density: 3 mg per sample at 100 Hz
STORED = Stored(static_norm_mg=0.3, acc_noise_density=DENSITY)
GYRO_DRIFT = np.radians([0.3, -0.25, 0.2])  # rad/s
ACC_DRIFT = np.array([0.006, -0.004, 0.008])  # g
ACC_SCALE_DRIFT = np.array([0.003, 0.0, -0.002])
FLAGS = ["-std=c99", "-O2", "-Wall", "-Wextra", "-pedantic", "-Wconversion", "-Werror"]


def calibration(truth) -> Calibration:
    return Calibration(segments=(SegmentModels(0.0, 0.0, truth.stored_acc, truth.stored_gyro),),
                       acc_unit_raw="g", acc_unit="g", g=1.0, gyro_unit_raw="rad/s")


def build(cal: Calibration, d: Path, extra: tuple[str, ...] = (), name: str = "driver") -> Path:
    inp = ExportInput(path=d / "calib.json", calibration=cal, source={},
                      noise={"accelerometer": {"white_noise_density": [DENSITY] * 3}},
                      quality={"static_norm_rms_mg": {"cross_validated": STORED.static_norm_mg}})
    for path, text in c_runtime.export(inp, d, None).files:
        path.write_text(text)
    (d / "driver.c").write_text(c_runtime.DRIVER_C)
    exe = d / name
    subprocess.run([CC, *FLAGS, *extra, "-o", str(exe), str(d / "driver.c"),
                    str(d / c_runtime.SOURCE), "-lm"], check=True, capture_output=True)
    return exe


def run(exe: Path, session, d: Path, first: int = 0) -> dict:
    np.column_stack([session.acc, session.gyro]).astype(np.float32).tofile(d / "in.bin")
    out = subprocess.run([str(exe), "100", str(d / "in.bin"), str(d / "out.bin"), "1",
                          str(first)], capture_output=True, text=True, check=True
                         ).stdout.splitlines()
    rows = [[float(x) for x in line.split()[1:]] for line in out if line.startswith("moment")]
    moments = np.array(rows).reshape(-1, 9)
    values = {line.split()[0]: line.split()[1:] for line in out if not line.startswith("moment")}
    return {"moments": moments, "bias": np.array(values["bias"], float),
            "acc_b": np.array(values["acc_b"], float), "acc_k": np.array(values["acc_k"], float),
            "acc_choice": [int(x) for x in values["acc_choice"]],
            "sizeof": int(values["sizeof"][0]),
            "out": np.fromfile(d / "out.bin", np.float32).reshape(-1, 15)}


@pytest.fixture(scope="module", params=["walk", "jumps", "desk"])
def case(request, tmp_path_factory):
    """Ten minutes of use (walk, jumps: a person's sway and taps; desk: typing and taps)
    with the gyroscope's bias and the accelerometer's biases and scales drifted, through the C
    runtime and through the Python."""
    d = tmp_path_factory.mktemp(request.param)
    session, truth = make_everyday(request.param, minutes=10, seed=0,
                                   drift=Drift(gyro_bias=GYRO_DRIFT, acc_bias=ACC_DRIFT,
                                               acc_scale=ACC_SCALE_DRIFT))
    cal = calibration(truth)
    c = run(build(cal, d), session, d)
    return session, truth, c, refresh(cal, STORED, session), d




def test_the_module_is_c99_without_allocation_or_dependency(case, tmp_path):
    session, truth, c, _, _ = case
    build(calibration(truth), tmp_path)  # -std=c99 -pedantic -Wconversion -Werror: clean
    text = (tmp_path / c_runtime.HEADER).read_text() + (tmp_path / c_runtime.SOURCE).read_text()
    assert set(re.findall(r"#include <([^>]+)>", text)) == {"math.h", "stdint.h"}
    assert not re.search(r"\b(malloc|calloc|realloc|free|double)\b", text)
    # the memory the header states is the compiler's sizeof
    assert c["sizeof"] == c_runtime.state_bytes(c_runtime.DEFAULT_MAX_RATE_HZ) == 6360
    header = (tmp_path / c_runtime.HEADER).read_text()
    assert "6360 bytes" in header
    assert "= 344 + 24 * IMUCAL_RT_RING + 16 * IMUCAL_RT_MAX_MOMENTS bytes" in header
    assert 344 + 24 * 208 + 16 * 64 == 6360


def test_calibrated_samples_agree_with_python_apply_to_float32_rounding(case):
    session, truth, c, _, _ = case
    out = c["out"]
    raw_a = session.acc.astype(np.float32).astype(np.float64)
    raw_g = session.gyro.astype(np.float32).astype(np.float64)
    # the accelerometer with the model in force at each sample (refitted as a moment ends)
    acc_b = np.vstack([truth.stored_acc.b, out[:-1, 9:12]])
    acc_k = np.vstack([truth.stored_acc.K, out[:-1, 12:15]])
    acc = np.einsum("ij,nj->ni", truth.stored_acc.T, acc_k * (raw_a - acc_b))
    np.testing.assert_allclose(out[:, :3], acc, rtol=0, atol=1e-6)  # measured 2e-7 (|a| ~ 1)
    assert np.ptp(out[:, 9:12], axis=0).max() > 0.003  # the accelerometer's bias did move
    # the gyroscope with the bias in force at each sample: the one reported after the sample
    # before (a moment's end moves it after its sample is out)
    bias = np.vstack([truth.stored_gyro.b, out[:-1, 6:9]])
    gyro = np.einsum("ij,nj->ni", truth.stored_gyro.matrix, raw_g - bias)
    scale = 1e-6 * np.maximum(np.abs(gyro), 1.0)
    assert np.all(np.abs(out[:, 3:6] - gyro) <= scale)
    assert np.ptp(out[:, 6:9], axis=0).max() > np.radians(0.1)  # the bias did move


def test_the_still_moments_are_the_python_detectors(case):
    """Measured on walk, jumps and desk (seed 0: 14, 30, 58 moments): the same [start, end)
    to the sample, none refused, and none over a tap or typing; the rates to 1e-4 deg/s."""
    session, truth, c, r, _ = case
    m = r.check.moments
    got = c["moments"]
    assert got[:, 2].all()
    np.testing.assert_array_equal(got[:, :2].astype(np.int64), m.blocks)
    assert m.count >= 10
    # M10's rate at rest of each moment: the Python's to float32 rounding
    np.testing.assert_allclose(got[:, 3:6], m.rate, rtol=0, atol=np.radians(1e-4))
    np.testing.assert_allclose(got[:, 6:9], m.rate_se, rtol=1e-3)
    t = session.t_acc
    for a, b in got[:, :2].astype(np.int64):
        d = truth.disturbed
        assert not np.any((d[:, 0] < t[b - 1]) & (d[:, 1] > t[a]))  # no moment on a tap


def test_the_refreshed_gyroscope_bias_is_pythons_and_the_truth(case):
    session, truth, c, r, _ = case
    # measured: at most 4e-7 deg/s from refresh.py's (float32 sums of float32 rates)
    np.testing.assert_allclose(np.degrees(c["bias"]), np.degrees(r.gyro.b), atol=1e-4)
    assert np.degrees(np.abs(c["bias"] - truth.gyro.b)).max() < 0.05  # measured 0.005
    # moved only once the moments add up to 3 s (refresh.py's rule), at the sample that ends
    # that moment (half a window of 51 after its last sample), the stored bias before
    got = c["moments"][:, :2].astype(np.int64)
    k = int(np.argmax(np.cumsum((got[:, 1] - 1 - got[:, 0]) / 100.0) >= 3.0))
    moved = np.flatnonzero(np.any(c["out"][:, 6:9] != np.float32(truth.stored_gyro.b), axis=1))
    assert moved[0] == got[k, 1] + 50


def true_still_norm_mg(truth, k: np.ndarray, b: np.ndarray) -> float:
    """The still-norm error RMS (mg) of the model (the stored T, scales ``k``, biases ``b``)
    on the true sensor at rest in 2000 directions over the sphere: what M9 would read."""
    u = np.random.default_rng(1).normal(size=(2000, 3))
    raw = truth.acc.invert(u / np.linalg.norm(u, axis=1, keepdims=True))
    cal = np.einsum("ij,nj->ni", truth.stored_acc.T, k * (raw - b))
    return float(np.sqrt(np.mean((np.linalg.norm(cal, axis=1) - 1.0) ** 2))) * 1e3


def test_the_refreshed_accelerometer_is_pythons_and_the_truth(case):
    """M11 refitted at each moment (estimate.fit_acc): after the last, the Python's choice
    and values to float32 rounding (measured: biases 4e-8 g, scales 1.3e-7 apart); with 20
    moments covering every axis at 0.3 g on both sides, the true still-norm error <= 3 mg
    (from 6-7 mg stored)."""
    session, truth, c, r, _ = case
    fit = r.check.acc_fit
    choice, covered = c["acc_choice"]
    assert ["none", "bias", "bias and scale"][choice] == fit.choice == "bias and scale"
    assert covered == sum(1 << i for i in range(3) if fit.covered[i]) == 7
    np.testing.assert_allclose(c["acc_b"], r.acc.b, rtol=0, atol=2e-7)
    np.testing.assert_allclose(c["acc_k"], r.acc.K, rtol=0, atol=5e-7)
    stored = true_still_norm_mg(truth, truth.stored_acc.K, truth.stored_acc.b)
    assert stored > 5.0
    assert true_still_norm_mg(truth, c["acc_k"], c["acc_b"]) < 1.0
    # after the 20th moment (the last, walking: 14), if the moments so far cover every axis
    got = c["moments"][:, :2].astype(np.int64)
    k = min(20, len(got)) - 1
    u = r.check.moments.cal_mean[: k + 1]
    assert np.all((u >= 0.3).any(axis=0) & (u <= -0.3).any(axis=0))
    # the sample that closed it (half a window of 51 on), or the stream's end (finish)
    at = got[k, 1] + 50
    kb = (c["out"][at, 12:15], c["out"][at, 9:12]) if at < len(c["out"]) else (c["acc_k"],
                                                                                  c["acc_b"])
    assert true_still_norm_mg(truth, *kb) <= 3.0
    # nothing moved before 6 moments
    first = c["out"][: got[min(5, len(got) - 1), 1] + 50]
    assert np.all(first[:, 9:12] == np.float32(truth.stored_acc.b))


def test_past_the_moments_held_the_fit_is_on_the_last_ones(case, tmp_path):
    """IMUCAL_RT_MAX_MOMENTS = 8: the device refits on the last 8 moments, which is
    estimate.fit_acc on those 8 (the Python fits them all)."""
    session, truth, c, r, _ = case
    if truth.activity != "desk":
        pytest.skip("once is enough (desk: 58 moments)")
    cal = calibration(truth)
    exe = build(cal, tmp_path, ("-DIMUCAL_RT_MAX_MOMENTS=8",), "driver8")
    few = run(exe, session, tmp_path)
    assert few["sizeof"] == c_runtime.state_bytes(c_runtime.DEFAULT_MAX_RATE_HZ, 8) == 5464
    m = r.check.moments
    last = dataclasses.replace(m, **{f: getattr(m, f)[-8:] for f in (
        "blocks", "times", "n", "raw_mean", "cal_mean", "norm_var", "rate", "rate_se")})
    fit = fit_acc(truth.stored_acc, last, 1.0, STORED.static_norm_mg * 1e-3, "g")
    assert ["none", "bias", "bias and scale"][few["acc_choice"][0]] == fit.choice
    np.testing.assert_allclose(few["acc_b"], fit.model.b, rtol=0, atol=2e-7)
    np.testing.assert_allclose(few["acc_k"], fit.model.K, rtol=0, atol=5e-7)
    assert np.abs(few["acc_b"] - r.acc.b).max() > 1e-6  # not the fit on all 58


def test_the_gyroscope_bias_after_each_moment_once_3_s_are_seen(case):
    """The issue's figure: within 0.05 deg/s of the truth after every moment once the moments
    add up to 3 s (each one is 2 s or more)."""
    session, truth, c, _, _ = case
    got = c["moments"][:, :2].astype(np.int64)
    k = int(np.argmax(np.cumsum((got[:, 1] - 1 - got[:, 0]) / 100.0) >= 3.0))
    after = c["out"][np.minimum(got[k:, 1] + 50, len(c["out"]) - 1), 6:9]
    assert np.degrees(np.abs(after - truth.gyro.b)).max() < 0.05


def test_a_sample_count_that_wraps_past_2_32_changes_nothing(case):
    """A wearable at 1 kHz counts past 2^32 samples in 49 days: the ring is addressed by age,
    so numbering the samples from just below 2^32 gives the same moments and bias."""
    session, truth, c, _, d = case
    first = 2**32 - 20000  # wraps in the middle of the recording
    wrapped = run(d / "driver", session, d, first)
    got = (wrapped["moments"][:, :2].astype(np.int64) - first) % 2**32
    np.testing.assert_array_equal(got, c["moments"][:, :2].astype(np.int64))
    np.testing.assert_array_equal(wrapped["bias"], c["bias"])
    np.testing.assert_array_equal(wrapped["out"], c["out"])


def test_a_nan_in_a_moment_refuses_it_and_spoils_nothing_else(case):
    session, truth, c, _, d = case
    if truth.activity != "walk":
        pytest.skip("once is enough")
    a, b = c["moments"][2, :2].astype(np.int64)
    gyro = session.gyro.copy()
    gyro[(a + b) // 2, 1] = np.nan
    bad = run(d / "driver", dataclasses.replace(session, gyro=gyro), d)
    np.testing.assert_array_equal(bad["moments"][:, :2], c["moments"][:, :2])
    assert list(bad["moments"][:, 2]) == [1, 1, 0] + [1] * (len(c["moments"]) - 3)
    assert np.all(np.isfinite(bad["bias"]))
    assert np.degrees(np.abs(bad["bias"] - truth.gyro.b)).max() < 0.05


def test_a_rate_beyond_the_state_is_refused(case):
    session, _, _, _, d = case
    np.zeros((10, 6), np.float32).tofile(d / "few.bin")
    for rate in ("1000", "4"):  # above IMUCAL_RT_MAX_RATE_HZ = 200; too slow for a window
        rc = subprocess.run([str(d / "driver"), rate, str(d / "few.bin"), str(d / "o.bin")],
                            capture_output=True).returncode
        assert rc == 5  # imucal_rt_init returned -1
    rc = subprocess.run([str(d / "driver"), "200", str(d / "few.bin"), str(d / "o.bin")],
                        capture_output=True).returncode
    assert rc == 0


def test_cli_writes_the_directory_and_refuses_a_calibration_without_noise(tmp_path, capsys):
    assert main(["synth", str(tmp_path / "w.mat"), "--activity", "walk", "--seed", "3"]) == 0
    calib = tmp_path / "w.mat.calib.json"
    out = tmp_path / "rt"
    assert main(["export", str(calib), "--to", "c-runtime", "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["imucal_runtime.c", "imucal_runtime.h"]
    # the stored density, as the float32 nearest it
    assert "NOISE_DENSITY = 0.000300000014f;" in (out / "imucal_runtime.c").read_text()
    data = json.loads(calib.read_text())
    del data["noise"]
    bare = tmp_path / "bare.json"
    bare.write_text(json.dumps(data))
    capsys.readouterr()
    assert main(["export", str(bare), "--to", "c-runtime", "--out", str(tmp_path / "x")]) == 1
    err = capsys.readouterr().err
    assert "noise.accelerometer.white_noise_density" in err and "Traceback" not in err
