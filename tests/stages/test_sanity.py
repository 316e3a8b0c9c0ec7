"""Wrong calibrations with exit 0 and no word (issue 11, item 5): raw counts that wrap around, a
gyroscope covering part of the session, a gap in the time, two files of different length at one
rate. Each is found, named where it happens, and either mended (the calibration then recovers
the truth as from the clean session) or refused in one line."""

from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import imucal
import imucal.pipeline as pipeline
from imucal.errors import ImucalError
from imucal.models import gyro_theta
from imucal.report import report
from imucal.stages.sanity import (
    one_rate_pairing,
    time_gaps,
    turns_without_gyro,
    unwrap_session,
)
from imucal.synth import make_session

BIN = Path(sys.executable).parent
IMUCAL = shutil.which("imucal", path=str(BIN)) or str(BIN / "imucal")


def _codes(result) -> dict[str, str]:
    return {w.code: w.text for w in result.warnings}


def _gravity_after(result) -> float:
    return result.quality.gravity_angle_rms_deg.after


def _run(*args, cwd: Path) -> subprocess.CompletedProcess:
    proc = subprocess.run([IMUCAL, *map(str, args)], cwd=cwd, capture_output=True, text=True,
                          timeout=300)
    assert "Traceback" not in proc.stderr, proc.stderr
    return proc


def _one_line_error(proc: subprocess.CompletedProcess, *needles: str) -> str:
    assert proc.returncode == 1, (proc.returncode, proc.stdout, proc.stderr)
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("imucal: error: "), proc.stderr
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]


# --- wrap-around -------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def counts16():
    """A raw-count session whose gyroscope (16000 counts per rad/s, centred on 32768) leaves
    the 16-bit register during the faster turns, and the same stored as uint16 (wrapped)."""
    session, truth = make_session(poses=30, seed=3, acc_unit="counts", gyro_unit="counts",
                                  counts_per_rad_s=16000.0)
    assert session.gyro.max() > 65535 or session.gyro.min() < 0
    wrapped = dataclasses.replace(session, gyro=session.gyro % 65536, source="wrapped.csv")
    return session, wrapped, truth, imucal.calibrate(session)


def test_int16_wrap_is_unwrapped_and_named(counts16, monkeypatch):
    clean, wrapped, truth, clean_result = counts16
    result = imucal.calibrate(wrapped)
    # The signal the calibration used is the original one, to the count.
    np.testing.assert_array_equal(result.session.gyro, clean.gyro)
    text = _codes(result)["gyro_wraparound"]
    assert "wrapped.csv" in text and "65536 counts (2^16)" in text
    # Where: the first wrapped sample of each axis, by index and time.
    for axis, name in enumerate("xyz"):
        bad = np.flatnonzero(wrapped.gyro[:, axis] != clean.gyro[:, axis])
        if len(bad):
            assert (f"gyroscope {name}: " in text
                    and f"first at sample {bad[0]} (t = {clean.t_gyro[bad[0]]:.3f} s)" in text)
    # The calibration recovers the truth as from the clean file (0.035 deg both) ...
    assert _gravity_after(result) < 1.2 * _gravity_after(clean_result) + 0.01
    g = result.segments[0].gyro
    err = np.abs(gyro_theta(g.model) - gyro_theta(truth.gyro)) / g.std[:9]
    assert err.max() < 4.0, err
    # ... where taken as it comes it was 50 deg off (issue 11).
    monkeypatch.setattr(pipeline, "unwrap_session", lambda s: (s, []))
    assert _gravity_after(imucal.calibrate(wrapped)) > 10.0


def test_12bit_signed_accelerometer_wrap_is_unwrapped():
    """A 12-bit two's-complement accelerometer (2000 counts per g, so +-1 g poses leave the
    register at +-2048): unwrapped by 4096, the calibration is the clean one's."""
    session, _ = make_session(poses=30, seed=4, acc_unit="counts", counts_per_g=2000.0)
    signed = dataclasses.replace(session, acc=session.acc - 32768.0)
    wrapped = dataclasses.replace(signed, acc=(signed.acc + 2048) % 4096 - 2048)
    assert np.count_nonzero(wrapped.acc != signed.acc) > 1000
    fixed, warnings = unwrap_session(wrapped)
    np.testing.assert_array_equal(fixed.acc, signed.acc)
    assert [w.code for w in warnings] == ["acc_wraparound"]
    assert "4096 counts (2^12)" in warnings[0].message
    a, b = imucal.calibrate(signed), imucal.calibrate(wrapped)
    assert b.quality.static_norm_rms_mg.after < 1.2 * a.quality.static_norm_rms_mg.after + 0.01
    np.testing.assert_allclose(b.segments[0].acc.model.K, a.segments[0].acc.model.K, rtol=1e-9)


def test_one_sample_off_by_65536_is_put_back():
    rng = np.random.default_rng(0)
    t = np.arange(5000) / 100.0
    x = np.rint(32768 + 50 * np.sin(t)[:, None] + rng.normal(0, 5, (5000, 3)))
    s = imucal.Session(acc=x.copy(), t_acc=t, gyro=x.copy(), t_gyro=t, acc_unit="counts",
                       gyro_unit="counts", source="a.txt + g.txt")
    bad = s.gyro.copy()
    bad[1234, 1] += 65536
    fixed, warnings = unwrap_session(dataclasses.replace(s, gyro=bad))
    np.testing.assert_array_equal(fixed.gyro, s.gyro)
    assert len(warnings) == 1 and warnings[0].code == "gyro_wraparound"
    assert ("gyroscope in g.txt" in warnings[0].message
            and "gyroscope y: 2 wraps of 65536 counts (2^16), 1 samples corrected, first at "
                "sample 1234 (t = 12.340 s)" in warnings[0].message)
    # Not integers (a signal in g or rad/s): never taken for counts.
    same, none = unwrap_session(dataclasses.replace(s, gyro=bad + 0.5))
    assert none == [] and same.gyro is not None and same.gyro[1234, 1] == bad[1234, 1] + 0.5


def _ambiguous(wrapped):
    """A stretch of ``wrapped`` raised by 40000 counts on gyroscope x: more than half the
    register that wraps elsewhere, and no power of two."""
    g = wrapped.gyro.copy()
    g[6000:6050, 0] += 40000
    return dataclasses.replace(wrapped, gyro=g)


def test_ambiguous_wrap_is_refused_in_one_line(counts16):
    bad = _ambiguous(counts16[1])
    with pytest.raises(ImucalError) as err:
        imucal.calibrate(bad)
    msg = str(err.value)
    assert msg.startswith("wrapped.csv: gyroscope x: a step of +"), msg
    assert "counts at sample 6000 (t = 60.000 s) is more than half of the 65536-count" in msg
    assert "cannot tell a wrap-around from a real jump" in msg and "\n" not in msg


def test_ambiguous_wrap_through_the_cli(counts16, tmp_path):
    bad = _ambiguous(counts16[1])
    data = np.column_stack([bad.t_acc, bad.acc, bad.gyro])
    np.savetxt(tmp_path / "wrapped.csv", data, delimiter=",", header="t,ax,ay,az,gx,gy,gz",
               comments="", fmt=["%.3f"] + ["%d"] * 6)
    proc = _run("calibrate", "wrapped.csv", "--out", "calib.json", cwd=tmp_path)
    _one_line_error(proc, "wrapped.csv", "gyroscope x", "sample 6000", "t = 60.000 s",
                    "wrap-around")
    assert not (tmp_path / "calib.json").exists()


def test_real_recordings_raise_no_false_alarm(shared_data):
    """The Xsens file is raw 16-bit counts spanning nearly its whole register (gyroscope
    1306-65352): no wrap, no gap; nor in the other recordings."""
    d = shared_data
    sessions = [imucal.load_session(d / "imu_tk_xsens" / "xsens_acc.mat",
                                    gyro_path=d / "imu_tk_xsens" / "xsens_gyro.mat"),
                imucal.load_session(d / "imucal_ferraris" / "example_ferraris_session.csv",
                                    rate=102.4)]
    sessions += [imucal.load_session(d / "mikoff_mpu9150" / f"imu{i}.log", rate=100.0)
                 for i in range(3)]
    xsens = sessions[0]
    assert xsens.acc_unit == "counts" and np.all(xsens.gyro == np.rint(xsens.gyro))
    for s in sessions:
        same, warnings = unwrap_session(s)
        assert warnings == [] and same is s, s.source
        assert len(time_gaps(s.t_acc)) == 0 and len(time_gaps(s.t_gyro)) == 0, s.source


def test_xsens_read_as_int16_is_unwrapped(shared_data, tmp_path):
    """The Xsens recording (unsigned 16-bit counts, zero near 32768) written as int16, the
    likely way of issue 11's case: 54 deg after when taken as it comes; unwrapped, the clean
    file's 0.48 deg exactly (each axis a whole register off the original: the bias absorbs it)."""
    src = shared_data / "imu_tk_xsens"
    for name in ("xsens_acc.mat", "xsens_gyro.mat"):
        m = np.loadtxt(src / name)
        m[:, 1:] = np.where(m[:, 1:] > 32767, m[:, 1:] - 65536, m[:, 1:])
        np.savetxt(tmp_path / name.replace(".mat", ".txt"), m, fmt=["%.6f"] + ["%d"] * 3)
    session = imucal.load_session(tmp_path / "xsens_acc.txt", gyro_path=tmp_path / "xsens_gyro.txt")
    clean = imucal.load_session(src / "xsens_acc.mat", gyro_path=src / "xsens_gyro.mat")
    result = imucal.calibrate(session)
    for fixed, raw in ((result.session.acc, clean.acc), (result.session.gyro, clean.gyro)):
        off = fixed - raw
        assert np.all(off == off[0]) and np.all(np.isin(off[0], (-65536, 0, 65536)))
    codes = _codes(result)
    assert "gyroscope x: " in codes["gyro_wraparound"]
    assert "xsens_acc.txt" in codes["acc_wraparound"]
    after = _gravity_after(result)
    assert abs(after - _gravity_after(imucal.calibrate(clean))) < 1e-6 and after < 0.5


# --- partial gyroscope coverage and gaps -------------------------------------------------------


@pytest.fixture(scope="module")
def clean5():
    session, truth = make_session(poses=30, seed=5)
    return session, truth, imucal.calibrate(session, single_segment=True)


def test_gyroscope_covering_half_the_session(clean5, monkeypatch):
    session, truth, clean = clean5
    n = len(session.gyro) // 2
    half = dataclasses.replace(session, gyro=session.gyro[:n], t_gyro=session.t_gyro[:n])
    result = imucal.calibrate(half, single_segment=True)
    # The blocks after the gyroscope's last sample, and the turns into and between them.
    bt = result.block_times
    dark = np.flatnonzero(bt[:, 0] > half.t_gyro[-1])
    assert len(dark) >= 10
    text = _codes(result)["gyro_no_data"]
    assert (f"t = 0.00-{half.t_gyro[-1]:.2f} s" in text
            and f"still blocks {dark[0]}-{dark[-1]} (of {len(bt)})" in text
            and f"turns {dark[0] - 1}-{len(bt) - 2} (of {len(bt) - 1}" in text), text
    g = result.segments[0].gyro
    assert np.flatnonzero(g.excluded).tolist() == list(range(dark[0] - 1, len(bt) - 1))
    # Fitted on what overlaps: the gravity error after is the clean file's, the parameters
    # the truth's; with every turn fitted it was 71 deg (issue 11: 67).
    assert _gravity_after(result) < 1.5 * _gravity_after(clean) + 0.02
    err = np.abs(gyro_theta(g.model) - gyro_theta(truth.gyro)) / g.std[:9]
    assert err.max() < 4.0, err
    gyro_details = report(result).segments[0].fits[1].details
    assert f"rotations ({int(g.excluded.sum())} left out of the fit)" in gyro_details
    monkeypatch.setattr(pipeline, "turns_without_gyro", lambda t, b, *_: np.zeros(len(b) - 1, bool))
    assert _gravity_after(imucal.calibrate(half, single_segment=True)) > 10.0


def test_time_gaps_on_a_batching_logger():
    """Samples stamped in batches (ten 1 ms apart, then 91 ms): a regular long step, no gap;
    five minutes inside such a clock still is one."""
    t = np.cumsum(np.tile(np.r_[np.full(9, 0.001), 0.091], 1000))
    assert len(time_gaps(t)) == 0
    t[5000:] += 300.0
    assert time_gaps(t).tolist() == [4999]


def test_gyroscope_covering_no_turn_is_refused(clean5):
    session, truth, _ = clean5
    n = int(np.mean(truth.pose_times[0]) * 100)  # ends during the first still pose
    short = dataclasses.replace(session, gyro=session.gyro[:n], t_gyro=session.t_gyro[:n])
    with pytest.raises(ImucalError) as err:
        imucal.calibrate(short, single_segment=True)
    assert str(err.value).startswith("gyroscope: rotations: none of the 29 rotations between "
                                     "still poses has usable gyroscope data"), str(err.value)


def test_gap_inside_a_still_pose_splits_its_block(clean5):
    session, _, clean = clean5
    blocks = clean.detection.blocks
    k = len(blocks) // 2
    i = int(blocks[k].mean())  # the middle of a still block: both halves stay long enough
    t = session.t_acc.copy()
    t[i:] += 300.0
    gapped = dataclasses.replace(session, t_acc=t, t_gyro=t.copy(), source="gap.csv")
    result = imucal.calibrate(gapped, single_segment=True)
    text = _codes(result)["time_gap"]
    assert (f"accelerometer and gyroscope time in gap.csv has 1 gap: 300 s after sample {i - 1} "
            f"(t = {t[i - 1]:.3f} to {t[i]:.3f} s)") in text, text
    det = result.detection
    assert len(det.blocks) == len(blocks) + 1
    assert not np.any((det.blocks[:, 0] < i) & (det.blocks[:, 1] > i))  # none spans the gap
    g = result.segments[0].gyro
    assert np.flatnonzero(g.excluded).tolist() == [k]  # the "turn" across the gap
    assert "turn " + str(k) + " (of" in _codes(result)["gyro_no_data"]
    assert _gravity_after(result) < 1.5 * _gravity_after(clean) + 0.02


def test_gap_with_a_turn_in_it(clean5, monkeypatch):
    """Five minutes missing from the middle of one pose to the middle of the next (the turn
    between them unrecorded): integrated across the gap that turn is meaningless."""
    session, truth, clean = clean5
    a, b = (int(np.mean(truth.pose_times[p]) * 100) for p in (14, 15))
    keep = np.r_[0:a, b:len(session.t_acc)]
    t = session.t_acc[keep].copy()
    t[a:] += 300.0
    gapped = dataclasses.replace(session, acc=session.acc[keep], t_acc=t,
                                 gyro=session.gyro[keep], t_gyro=t.copy())
    result = imucal.calibrate(gapped, single_segment=True)
    assert f"after sample {a - 1} (t = {t[a - 1]:.3f} to {t[a]:.3f} s)" in \
        _codes(result)["time_gap"]
    g = result.segments[0].gyro
    across = turns_without_gyro(t, result.block_times)
    assert across.sum() == 1 and np.array_equal(g.excluded, across)
    assert _gravity_after(result) < 1.5 * _gravity_after(clean) + 0.02  # 0.037 deg, clean 0.038
    monkeypatch.setattr(pipeline, "turns_without_gyro", lambda t, b, *_: np.zeros(len(b) - 1, bool))
    assert _gravity_after(imucal.calibrate(gapped, single_segment=True)) > \
        5 * _gravity_after(result)  # 0.475 deg with the turn across the gap fitted


# --- two files, one rate -----------------------------------------------------------------------


def test_one_rate_pairing_rule():
    t = np.arange(15000) / 100.0
    assert one_rate_pairing(t, t, 100.0, "a.csv", "g.csv") is None
    note = one_rate_pairing(t, t[:14900], 100.0, "a.csv", "g.csv")
    assert note is not None and ("a.csv has 15000 samples (150.00 s) and g.csv 14900 (149.00 s) "
                                 "at --rate 100 Hz") in note and "last 1.00 s" in note
    with pytest.raises(ImucalError) as err:
        one_rate_pairing(t, t[:7500], 100.0, "a.csv", "g.csv")
    assert str(err.value).startswith("a.csv + g.csv: rate: files of different length at one "
                                     "rate: a.csv has 15000 samples (150.00 s) and g.csv 7500 "
                                     "(75.00 s)")
    # Timestamps from time columns: not this check's business (coverage is).
    assert one_rate_pairing(t + 0.5, t[:7500], 100.0, "a.csv", "g.csv") is None


@pytest.fixture(scope="module")
def two_files(tmp_path_factory, clean5):
    session = clean5[0]
    d = tmp_path_factory.mktemp("rate")
    np.savetxt(d / "acc.csv", session.acc, delimiter=",", fmt="%.6f")
    np.savetxt(d / "gyro_half.csv", session.gyro[: len(session.gyro) // 2], delimiter=",",
               fmt="%.6f")
    n = len(session.gyro) - 50  # the gyroscope's logger stopped half a second earlier
    np.savetxt(d / "gyro_short.csv", session.gyro[:n], delimiter=",", fmt="%.6f")
    return d, len(session.acc), n


def test_files_of_very_different_length_at_one_rate_are_refused(two_files):
    d, n_acc, _ = two_files
    proc = _run("calibrate", "acc.csv", "--gyro", "gyro_half.csv", "--rate", "100", "--out",
                "calib.json", cwd=d)
    _one_line_error(proc, "acc.csv", "gyro_half.csv", f"{n_acc} samples",
                    f"{n_acc // 2} ({n_acc // 2 / 100:.2f} s)", "--rate 100 Hz")
    assert not (d / "calib.json").exists()


def test_files_slightly_different_at_one_rate_warn(two_files):
    d, n_acc, n_gyro = two_files
    proc = _run("calibrate", "acc.csv", "--gyro", "gyro_short.csv", "--rate", "100", "--out",
                "short.json", cwd=d)
    assert proc.returncode == 0, proc.stderr
    said = (f"acc.csv has {n_acc} samples ({n_acc / 100:.2f} s) and gyro_short.csv {n_gyro} "
            f"({n_gyro / 100:.2f} s) at --rate 100 Hz")
    assert said in proc.stdout + proc.stderr
    codes = {w["code"] for w in json.loads((d / "short.json").read_text())["warnings"]}
    assert "lengths_differ" in codes


def test_largest_steps_across_chunk_edges_equal_numpy_whole():
    from imucal.stages.sanity import _largest_steps

    rng = np.random.default_rng(5)
    x = np.rint(rng.standard_normal((1000, 3)) * 50)
    x[700, 1] += 30000  # one big step, just past a chunk's edge with rows=7 below
    for rows in (7, 64, 1 << 16):
        assert np.array_equal(_largest_steps(x, rows), np.abs(np.diff(x, axis=0)).max(axis=0))
