"""Noise figures: the overlapping Allan estimator against a brute-force one, recovery of known
white noise and random walk from synthetic signals, the still blocks of a calibration, and the
``imucal noise`` command on files it streams in chunks."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import imucal
from imucal.io.noise_file import measure_noise
from imucal.io.noise_json import kalibr_block, noise_to_dict
from imucal.numerics.allan import (
    BIAS_INSTABILITY_FACTOR,
    AllanAccumulator,
    allan_variance,
    fit_noise,
    pooled_allan_variance,
)
from imucal.stages.noise import still_noise
from imucal.synth import make_session

BIN = Path(sys.executable).parent
IMUCAL = shutil.which("imucal", path=str(BIN)) or str(BIN / "imucal")
G_N = 9.80665


def brute_avar(x: np.ndarray, m: int) -> float:
    """The textbook overlapping Allan variance (every start point), one column."""
    ybar = np.convolve(x, np.ones(m) / m, mode="valid")  # the m-sample averages
    d = ybar[m:] - ybar[:-m]
    return float(0.5 * np.mean(d**2))


def white_and_walk(n: int, dt: float, N: np.ndarray, K: np.ndarray, seed: int) -> np.ndarray:
    """White noise of density N (unit/sqrt(Hz)) plus a random walk of K (unit/s/sqrt(Hz)):
    per sample sigma = N / sqrt(dt), walk steps K sqrt(dt) (IEEE 952 Annex C)."""
    rng = np.random.default_rng(seed)
    white = rng.normal(size=(n, len(N))) * N / np.sqrt(dt)
    walk = np.cumsum(rng.normal(size=(n, len(K))) * K * np.sqrt(dt), axis=0)
    return white + walk


# --- the estimator --------------------------------------------------------------------------------


def test_full_overlap_equals_the_textbook_estimator():
    x = white_and_walk(20000, 0.01, np.array([1e-3]), np.array([1e-3]), seed=1)[:, 0] + 9.81
    curve = allan_variance(x, overlap=None)
    for m, av in zip(curve.lags, curve.avar[:, 0]):
        assert av == pytest.approx(brute_avar(x, int(m)), rel=1e-9), m


def test_streaming_in_odd_chunks_equals_one_pass_and_strided_terms_stay_close():
    x = white_and_walk(150000, 0.01, np.array([1e-3, 2e-3]), np.array([1e-4, 0.0]), seed=2)
    whole = allan_variance(x, overlap=64)
    acc = AllanAccumulator(2, max_octave=whole.lags.size + 2)
    for lo in range(0, len(x), 7919):  # a prime: chunk edges fall everywhere
        acc.update(x[lo:lo + 7919])
    streamed = acc.curve()
    assert np.array_equal(streamed.lags, whole.lags)
    assert np.allclose(streamed.avar, whole.avar, rtol=1e-9)
    full = allan_variance(x, overlap=None)
    assert np.array_equal(full.lags, whole.lags)
    small = whole.lags <= 64
    assert np.allclose(whole.avar[small], full.avar[small], rtol=1e-12)  # every start point
    assert np.allclose(whole.avar, full.avar, rtol=0.02)  # a stride of m/64 beyond


def test_the_accumulator_holds_a_bounded_number_of_sums():
    acc = AllanAccumulator(3)
    rng = np.random.default_rng(3)
    for _ in range(40):
        acc.update(rng.normal(size=(50000, 3)))
    assert acc.n == 2_000_000
    kept = sum(t.shape[0] for t in acc.tails)
    assert kept <= 2 * 64 * len(acc.lags)  # 2 m / stride per lag: independent of the length


def test_pooled_variance_counts_only_clusters_inside_one_run():
    x = white_and_walk(6000, 0.01, np.array([1e-3]), np.array([1e-3]), seed=4)[:, 0]
    x[2000:] += 5.0  # a jump between runs must not show
    starts, ends = np.array([0, 2500, 4000]), np.array([2000, 3700, 6000])
    curve = pooled_allan_variance(x[:, None], starts, ends)
    for m, av in zip(curve.lags, curve.avar[:, 0]):
        num = den = 0.0
        for a, b in zip(starts, ends):
            if b - a >= 2 * m:
                ybar = np.convolve(x[a:b], np.ones(m) / m, mode="valid")
                d = ybar[m:] - ybar[:-m]
                num += 0.5 * np.sum(d**2)
                den += len(d)
        assert av == pytest.approx(num / den, rel=1e-9)
    assert curve.lags.max() * 3 <= 2000


# --- recovery of known figures --------------------------------------------------------------------


def test_white_noise_and_random_walk_recovered_within_ten_percent():
    """One hour at 100 Hz, the white / random-walk crossover at 1 s (sqrt(3) N / K): three
    decades of each slope."""
    dt = 0.01
    N = np.array([1e-3, 2e-3, 5e-4])
    K = np.sqrt(3.0) * N / 1.0
    x = white_and_walk(360_000, dt, N, K, seed=5)
    curve = allan_variance(x, overlap=64)
    for i in range(3):
        f = fit_noise(curve, dt, i)
        assert f.white == pytest.approx(N[i], rel=0.1)
        assert f.random_walk == pytest.approx(K[i], rel=0.1)
        # Honest error bars: the truth within three of them.
        assert abs(f.white / N[i] - 1) < 3 * f.white_rel_err
        assert abs(f.random_walk / K[i] - 1) < 3 * f.random_walk_rel_err
        # White + random walk: the minimum deviation is sqrt(2 N K / sqrt(3)) (at tau =
        # sqrt(3) N / K), read as "bias instability" = minimum / 0.664.
        bi = np.sqrt(2 * N[i] * K[i] / np.sqrt(3.0)) / BIAS_INSTABILITY_FACTOR
        assert f.bias_instability == pytest.approx(bi, rel=0.1)


def test_too_short_a_record_says_so_instead_of_inventing():
    dt = 0.01
    x = white_and_walk(30_000, dt, np.array([1e-3]), np.array([1e-5]), seed=6)
    f = fit_noise(allan_variance(x, overlap=64), dt, 0)
    assert f.white == pytest.approx(1e-3, rel=0.1)
    assert f.random_walk is None and f.bias_instability is None
    assert any("record too short" in w for w in f.why)


def test_an_anti_alias_filter_does_not_bias_the_white_noise():
    """Oversampled, low-passed white noise: the shortest lags sit below the -1/2 line and the
    fit starts past them."""
    dt = 0.001
    rng = np.random.default_rng(7)
    w = rng.normal(size=400_000) / np.sqrt(dt) * 1e-3  # density 1e-3 before the filter
    k = np.ones(8) / 8  # an 8-sample moving average: unity gain at low frequency
    x = np.convolve(w, k, mode="same")
    curve = allan_variance(x[:, None], overlap=64)
    f = fit_noise(curve, dt, 0)
    assert f.fit_from_tau > dt  # the filtered lags were skipped
    assert f.white == pytest.approx(1e-3, rel=0.1)


# --- the still blocks of a calibration ------------------------------------------------------------


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    session, truth = make_session(poses=26, seed=8, acc_noise=0.004, gyro_noise=0.002,
                                  acc_rate=200.0, gyro_rate=100.0)
    result = imucal.calibrate(session)
    path = tmp_path_factory.mktemp("cal") / "calib.json"
    imucal.save_calibration(result, path)
    return path, result, truth


def test_calibration_file_holds_the_still_block_noise_with_units(calibrated):
    path, result, truth = calibrated
    noise = json.loads(path.read_text())["noise"]
    acc, gyro = noise["accelerometer"], noise["gyroscope"]
    assert acc["white_noise_density_unit"] == "g/sqrt(Hz)"
    assert gyro["white_noise_density_unit"] == "rad/s/sqrt(Hz)"
    assert acc["rate_hz"] == pytest.approx(200.0) and gyro["rate_hz"] == pytest.approx(100.0)
    # Per-sample sigma through the calibration (|row of T K| ~ K) over sqrt(rate).
    seg = result.segments[0]
    want_acc = 0.004 * np.linalg.norm(seg.acc.model.matrix, axis=1) / np.sqrt(200.0)
    want_gyro = 0.002 * np.linalg.norm(seg.gyro.model.matrix, axis=1) / np.sqrt(100.0)
    assert np.allclose(acc["white_noise_density"], want_acc, rtol=0.1)
    assert np.allclose(gyro["white_noise_density"], want_gyro, rtol=0.1)
    # Blocks of a few seconds cannot show a random walk or a bias instability: null, and why.
    assert acc["random_walk"] == [None, None, None]
    assert acc["bias_instability"] == [None, None, None]
    assert any("record too short" in n for n in acc["notes"])
    assert "still blocks" in noise["source"]
    assert max(acc["allan_deviation"]["tau_s"]) * 3 <= max(
        b - a for a, b in result.block_times) + 1e-9


def test_still_noise_ignores_the_motion_between_blocks(calibrated):
    _, result, _ = calibrated
    everything = still_noise(result.calibrated, np.array([[result.calibrated.t_acc[0],
                                                           result.calibrated.t_acc[-1]]]))
    blocks = still_noise(result.calibrated, result.block_times)
    # At the longest lag the blocks allow (about a second), the turns dominate the whole
    # session's deviation; within the blocks it stays on the white noise's -1/2 line.
    b = blocks.accelerometer
    m = b.curve.lags[-1]
    dev_blocks = np.sqrt(b.curve.avar[-1])
    j = int(np.flatnonzero(everything.accelerometer.curve.lags == m)[0])
    dev_all = np.sqrt(everything.accelerometer.curve.avar[j])
    assert np.all(dev_all > 10 * dev_blocks)
    m3 = b.curve.lags[-3]  # a shorter lag: more clusters, a steadier estimate
    white = np.array(b.per_axis("white"))
    assert np.allclose(np.sqrt(b.curve.avar[-3]), white / np.sqrt(m3 / b.rate_hz), rtol=0.2)


# --- imucal noise on files ------------------------------------------------------------------------


def write_still_csv(path: Path, seconds: float, rate: float, seed: int, *, header=True,
                    gyro_deg=False) -> dict:
    dt = 1.0 / rate
    n = int(seconds * rate)
    truth = {"acc_N": np.array([2e-3, 2e-3, 3e-3]), "acc_K": np.array([3.5e-3, 3.5e-3, 5e-3]),
             "gyro_N": np.array([1e-4, 1.5e-4, 1e-4]), "gyro_K": np.array([1.7e-4, 2.6e-4,
                                                                         1.7e-4])}
    acc = white_and_walk(n, dt, truth["acc_N"], truth["acc_K"], seed) + [0.1, -0.2, 9.81]
    gyro = white_and_walk(n, dt, truth["gyro_N"], truth["gyro_K"], seed + 1) + [0.01, 0, -0.02]
    if gyro_deg:
        gyro = np.degrees(gyro)
    t = np.arange(n) * dt
    cols = [acc, gyro] if not header else [t[:, None], acc, gyro]
    table = np.hstack(cols)
    head = "t,ax,ay,az,gx,gy,gz" if header else ""
    np.savetxt(path, table, fmt="%.9g", delimiter="," if header else " ", header=head,
               comments="")
    return truth


def test_streamed_chunks_give_the_figures_of_one_pass(tmp_path):
    path = tmp_path / "still.csv"
    write_still_csv(path, 600, 100.0, seed=9)
    one = measure_noise(path, gyro_unit="rad/s", chunk_bytes=1 << 30)
    many = measure_noise(path, gyro_unit="rad/s", chunk_bytes=300_000)
    assert "1 chunk" in one.source and "chunks" in many.source
    assert int(many.source.split("read in ")[1].split()[0]) > 10
    for a, b in ((one.accelerometer, many.accelerometer), (one.gyroscope, many.gyroscope)):
        assert a.curve.n == b.curve.n == 60_000
        assert np.allclose(a.curve.avar, b.curve.avar, rtol=1e-9)
        assert a.rate_hz == pytest.approx(100.0)


def test_headerless_file_with_a_rate_keeps_one_clock_across_chunks(tmp_path):
    path = tmp_path / "still.txt"
    write_still_csv(path, 300, 50.0, seed=10, header=False)
    rep = measure_noise(path, rate=50.0, gyro_unit="rad/s", chunk_bytes=200_000)
    assert rep.accelerometer.rate_hz == pytest.approx(50.0, rel=1e-9)
    assert not any("gaps" in n for n in rep.notes)


@pytest.mark.skipif(not Path(IMUCAL).exists(), reason="the imucal script is not installed")
def test_cli_noise_recovers_known_figures_and_writes_kalibr(tmp_path):
    # Crossover sqrt(3) N / K = 1 s, 40 minutes at 100 Hz: long enough for both slopes.
    path = tmp_path / "still.csv"
    truth = write_still_csv(path, 2400, 100.0, seed=11)
    proc = subprocess.run([IMUCAL, "noise", str(path), "--gyro-unit", "rad/s", "--out",
                           "n.json", "--kalibr", "imu.yaml", "--chunk-mb", "2"],
                          capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "kalibr imu.yaml" in proc.stdout
    doc = json.loads((tmp_path / "n.json").read_text())
    acc, gyro = doc["noise"]["accelerometer"], doc["noise"]["gyroscope"]
    assert acc["unit"] == "m/s^2" and gyro["unit"] == "rad/s"
    assert np.allclose(acc["white_noise_density"], truth["acc_N"], rtol=0.1)
    assert np.allclose(acc["random_walk"], truth["acc_K"], rtol=0.1)
    assert np.allclose(gyro["white_noise_density"], truth["gyro_N"], rtol=0.1)
    assert np.allclose(gyro["random_walk"], truth["gyro_K"], rtol=0.1)
    kalibr = {}
    for line in (tmp_path / "imu.yaml").read_text().splitlines():
        if line and not line.startswith("#"):
            key, _, value = line.partition(":")
            kalibr[key] = json.loads(value.split("#")[0].strip())
    assert kalibr["accelerometer_noise_density"] == pytest.approx(truth["acc_N"].max(), rel=0.1)
    assert kalibr["accelerometer_random_walk"] == pytest.approx(truth["acc_K"].max(), rel=0.1)
    assert kalibr["gyroscope_noise_density"] == pytest.approx(truth["gyro_N"].max(), rel=0.1)
    assert kalibr["gyroscope_random_walk"] == pytest.approx(truth["gyro_K"].max(), rel=0.1)
    assert kalibr["update_rate"] == pytest.approx(100.0)
    assert kalibr["rostopic"] == "/imu0"


@pytest.mark.skipif(not Path(IMUCAL).exists(), reason="the imucal script is not installed")
def test_cli_noise_refuses_to_guess_a_still_gyroscope_unit(tmp_path):
    path = tmp_path / "still.csv"
    write_still_csv(path, 60, 100.0, seed=12, gyro_deg=True)
    proc = subprocess.run([IMUCAL, "noise", str(path)], capture_output=True, text=True,
                          cwd=tmp_path, timeout=120)
    assert proc.returncode == 1
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "give --gyro-unit" in lines[0] and "still.csv" in lines[0]


def test_calibrated_noise_is_in_calibrated_units(tmp_path, calibrated):
    """With a calibration the figures are measured on calibrated signals: a raw file in g
    calibrated to g, through the scale of T K."""
    cal_path, result, _ = calibrated
    path = tmp_path / "still.csv"
    dt = 0.005
    n = 120_000
    rng = np.random.default_rng(13)
    acc = rng.normal(size=(n, 3)) * 2e-4 / np.sqrt(dt) + [0.0, 0.0, 1.0]  # raw in g
    gyro = rng.normal(size=(n, 3)) * 1e-4 / np.sqrt(dt)
    t = np.arange(n) * dt
    np.savetxt(path, np.column_stack([t, acc, gyro]), fmt="%.9g", delimiter=",",
               header="t,ax,ay,az,gx,gy,gz", comments="")
    cal = imucal.load_calibration(cal_path)
    rep = measure_noise(path, calibration=cal, gyro_unit="rad/s")
    A = result.segments[0].acc.model.matrix
    want = 2e-4 * np.linalg.norm(A, axis=1)
    assert rep.accelerometer.unit == "g"
    assert np.allclose(rep.accelerometer.per_axis("white"), want, rtol=0.1)
    block, _ = kalibr_block(noise_to_dict(rep))
    assert block["accelerometer_noise_density"] == pytest.approx(want.max() * G_N, rel=0.1)


def test_noise_recording_reads_back(tmp_path):
    rr = pytest.importorskip("rerun")
    from viewer.noise import save_noise_recording

    path = tmp_path / "still.csv"
    write_still_csv(path, 120, 100.0, seed=14)
    data = noise_to_dict(measure_noise(path, gyro_unit="rad/s"))
    save_noise_recording(data, tmp_path / "n.rrd")
    found = {}
    for chunk in rr.chunk.RrdReader(tmp_path / "n.rrd").stream().filter(
            content="/noise/accelerometer/values"):
        batch = chunk.to_record_batch()
        for name in ("tau_s", "white"):
            col = [c for c in batch.schema.names if c.endswith(name)][0]
            found[name] = np.array(batch.column(col).to_pylist()[0], dtype=float)
    assert np.allclose(found["tau_s"], data["accelerometer"]["allan_deviation"]["tau_s"])
    assert np.allclose(found["white"], data["accelerometer"]["white_noise_density"])


def test_a_recording_that_moves_is_called_out(sample_session_path):
    """The sample is a calibration session: poses and turns, mostly motion (issue 27)."""
    with pytest.raises(imucal.ImucalError, match="is mostly motion, not a still recording"):
        measure_noise(sample_session_path, gyro_unit="rad/s")
