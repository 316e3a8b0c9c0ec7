"""``imucal noise`` on a still recording that is not quite still (issue 27): a knock is found and
left out, the figures stay those of the sensor, and a recording that is mostly motion is
refused."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from imucal.errors import ImucalError
from imucal.io.export import write_session_csv
from imucal.io.noise_file import measure_noise
from imucal.numerics.allan import AllanAccumulator, pooled_allan_variance
from imucal.stages.noise import not_still
from imucal.synth import make_session


def still_csv(path: Path, seconds: float, rate: float, seed: int,
              knocks: tuple[float, ...] = ()) -> dict:
    """White noise plus random walk (the figures of test_noise's still recording), with a
    knock of five samples at +3 g on z at each time of ``knocks``."""
    dt = 1.0 / rate
    n = int(seconds * rate)
    rng = np.random.default_rng(seed)
    N = np.array([2e-3, 2e-3, 3e-3, 1e-4, 1.5e-4, 1e-4])
    K = np.array([3.5e-3, 3.5e-3, 5e-3, 1.7e-4, 2.6e-4, 1.7e-4])
    x = (rng.normal(size=(n, 6)) * N / np.sqrt(dt)
         + np.cumsum(rng.normal(size=(n, 6)) * K * np.sqrt(dt), axis=0)
         + [0.1, -0.2, 9.81, 0.01, 0.0, -0.02])
    for k in knocks:
        i = int(k * rate)
        x[i:i + 5, 2] += 3 * 9.80665
    t = np.arange(n) * dt
    np.savetxt(path, np.column_stack([t, x]), fmt="%.9g", delimiter=",",
               header="t,ax,ay,az,gx,gy,gz", comments="")
    return {"acc_N": N[:3], "acc_K": K[:3], "gyro_N": N[3:]}


def test_restarted_accumulator_pools_like_the_still_blocks():
    """Stretches fed with a restart between them give the pooled Allan variance of those
    stretches, to rounding: no cluster spans a gap."""
    rng = np.random.default_rng(1)
    x = rng.normal(size=(5000, 3)) + np.cumsum(rng.normal(size=(5000, 3)) * 0.05, axis=0)
    lo, hi = np.array([0, 1700, 3100]), np.array([1500, 3000, 5000])
    acc = AllanAccumulator(3)
    for a, b in zip(lo, hi):
        if a:
            acc.restart()
        acc.update(x[a:b])
    ref = pooled_allan_variance(x, lo, hi)
    got = acc.curve()
    assert got.n == int(np.sum(hi - lo)) and acc.longest == 1900
    common = np.intersect1d(got.lags, ref.lags)
    assert len(common) >= 6
    g = got.avar[np.searchsorted(got.lags, common)]
    r = ref.avar[np.searchsorted(ref.lags, common)]
    assert np.allclose(g, r, rtol=0.05)
    # Fed without the restarts, the jumps between stretches would count as noise.
    whole = AllanAccumulator(3)
    for a, b in zip(lo, hi):
        whole.update(x[a:b] + (100.0 if a == 1700 else 0.0))
    assert whole.curve().avar[0].max() > 2 * g[0].max()


def test_not_still_finds_a_knock_and_nothing_in_plain_noise():
    rng = np.random.default_rng(2)
    t = np.arange(60_000) * 0.01
    x = rng.normal(size=(60_000, 3)) * 0.02 + [0.1, 0.0, 9.81]
    assert not not_still(t, x).any()
    x[30_000:30_005, 2] += 29.4
    off = not_still(t, x)
    assert np.array_equal(np.flatnonzero(off), np.arange(30_000, 30_005))


def test_one_knock_in_twenty_minutes_leaves_the_figures_unchanged(tmp_path):
    """Before issue 27 five samples at 3 g raised z's white noise 12.6 times and hid its
    random walk."""
    clean, knocked = tmp_path / "clean.csv", tmp_path / "knock.csv"
    truth = still_csv(clean, 1200, 100.0, seed=11)
    still_csv(knocked, 1200, 100.0, seed=11, knocks=(600.0,))
    ref = measure_noise(clean, gyro_unit="rad/s", chunk_bytes=2 << 20)
    rep = measure_noise(knocked, gyro_unit="rad/s", chunk_bytes=2 << 20)
    assert not any("not still" in n for n in ref.notes)
    for i in range(3):
        assert rep.accelerometer.fits[i].white == pytest.approx(truth["acc_N"][i], rel=0.1)
        assert rep.accelerometer.fits[i].random_walk == pytest.approx(truth["acc_K"][i],
                                                                      rel=0.15)
        assert rep.accelerometer.fits[i].white == pytest.approx(ref.accelerometer.fits[i].white,
                                                                rel=0.01)
        assert rep.gyroscope.fits[i].white == pytest.approx(truth["gyro_N"][i], rel=0.1)
    said = [n for n in rep.notes if "not still" in n]
    assert len(said) == 1 and "left out 1 stretch" in said[0] and "t = 600 s" in said[0]


def test_a_knock_across_a_chunk_boundary_is_left_out_once(tmp_path):
    path = tmp_path / "knock.csv"
    still_csv(path, 300, 100.0, seed=4, knocks=(100.0, 200.0))
    one = measure_noise(path, gyro_unit="rad/s", chunk_bytes=1 << 30)
    many = measure_noise(path, gyro_unit="rad/s", chunk_bytes=100_000)
    for rep in (one, many):
        z = rep.accelerometer.fits[2].white
        assert z == pytest.approx(3e-3, rel=0.1)
    assert "left out 2 stretches" in " ".join(one.notes)


def test_a_moving_recording_in_raw_counts_is_refused(tmp_path):
    """A calibration session (poses and turns) in counts is not a still recording."""
    sess, _ = make_session(poses=20, seed=2, acc_unit="counts", gyro_unit="counts")
    path = tmp_path / "moving.csv"
    write_session_csv(path, sess)
    with pytest.raises(ImucalError, match="mostly motion") as e:
        measure_noise(path, acc_unit="counts", gyro_unit="counts")
    assert "moving.csv" in str(e.value) and "\n" not in str(e.value)


def tilting_csv(path: Path, seconds: float = 600.0, rate: float = 100.0,
                degrees: float = 20.0) -> Path:
    """A recording that tilts slowly (``degrees`` over its length), white noise on top: still
    sample by sample, its gravity moving over minutes."""
    rng = np.random.default_rng(3)
    t = np.arange(int(seconds * rate)) / rate
    ang = np.radians(degrees) * t / t[-1]
    acc = np.column_stack([np.sin(ang), np.zeros_like(t), np.cos(ang)])
    acc += rng.normal(size=acc.shape) * 2e-3
    gyro = rng.normal(size=acc.shape) * 1e-3 + [0.0, np.radians(degrees) / t[-1], 0.0]
    np.savetxt(path, np.column_stack([t, acc, gyro]), fmt="%.9g", delimiter=",",
               header="t,ax,ay,az,gx,gy,gz", comments="")
    return path


def test_a_slow_tilt_is_not_taken_for_knocks(tmp_path):
    """Nothing of a slow tilt is left out (each second is still); the Allan deviation at long
    taus says the recording does not look still, as before."""
    rep = measure_noise(tilting_csv(tmp_path / "tilt.csv"), gyro_unit="rad/s")
    assert not any("left out" in n for n in rep.notes)
    assert any("does not look still" in n for n in rep.notes)
    assert rep.accelerometer.curve.n == 60_000
