"""Several triads through the command line (method.md §11, §12, M18): imucal synth's second
triad, range, shake and temperature -> calibrate --all-imus -> apply, the rows read back against
the synthetic truth (the specific force and body rate the session was made from)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import polars as pl
import pytest
from scipy.io import loadmat

from imucal.numerics import quaternion as quat
from imucal.synth import make_motion, specific_force

POSES = 20


def _imucal(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    code = "import sys; from imucal.cli import main; sys.exit(main())"
    proc = subprocess.run([sys.executable, "-c", code, *args], cwd=cwd, capture_output=True,
                          text=True, timeout=180)
    assert "Traceback" not in proc.stderr, proc.stderr
    return proc


def _ok(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    proc = _imucal(*args, cwd=cwd)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return proc


def _truth(t: np.ndarray, seed: int, shake: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The specific force (g) and body rate (rad/s) the synthetic session read, in the first
    triad's frame, and a mask of the still samples away from the turns' ends."""
    motion = make_motion(np.random.default_rng(seed), POSES, 3.0, 2.0, 5.0)
    q, w = motion.at(t)
    still = np.zeros(len(t), bool)
    for a, b in motion.still:
        still |= (t >= a + 0.3) & (t <= b - 0.3)
    return quat.rotate_inverse(q, specific_force(motion, t, shake, seed)), w, still


def _xyz(d: pl.DataFrame, prefix: str) -> np.ndarray:
    return d.select([f"{prefix}x", f"{prefix}y", f"{prefix}z"]).to_numpy()


def _block_error_mg(x: np.ndarray, ideal: np.ndarray, t: np.ndarray, seed: int) -> float:
    """RMS over the still poses of |mean(x - ideal)| in mg: the calibration's error, the noise
    averaged away."""
    motion = make_motion(np.random.default_rng(seed), POSES, 3.0, 2.0, 5.0)
    errs = [np.linalg.norm((x[m] - ideal[m]).mean(axis=0)) * 1e3
            for m in ((t >= a + 0.3) & (t <= b - 0.3) for a, b in motion.still)]
    return float(np.sqrt(np.mean(np.square(errs))))


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_low_and_high_range_pair_combined(tmp_path: Path, seed: int):
    _ok("synth", "s.csv", "--seed", str(seed), "--poses", str(POSES), "--acc-range", "2",
        "--shake", "3", "--acc2", "8", "--gyro2", cwd=tmp_path)
    truth = json.loads((tmp_path / "s.csv.truth.json").read_text())
    assert truth["accelerometer_range"] == 2.0 and truth["shake_g"] == 3.0
    (tri,) = truth["triads"]
    assert tri["range"] == 8.0 and tri["gyroscope"] is not None
    R = np.array(tri["rotation_to_reference"])
    cal = _ok("calibrate", "s.csv", "--out", "c.json", "--all-imus", cwd=tmp_path)
    c = json.loads((tmp_path / "c.json").read_text())["triads"]["combined"]
    assert (c["low_range"], c["high_range"]) == ("acc a", "acc a2")
    assert c["low_range_limits_raw"] == {"lo": [-2.0, -2.0, -2.0], "hi": [2.0, 2.0, 2.0],
                                         "how": "found in the data"}
    step, noise = c["step_at_switch_mg"], c["high_range_noise_mg"]
    assert 5.0 < noise < 7.0  # the 8 g triad's 6 mg per sample, found in the still blocks
    assert step["samples"] > 100 and step["norm"] < 3 * noise  # the bound
    assert step["norm"] < 3.5 + 3 * step["std"]  # and the calibrations' agreement near 2 g
    assert f"the step at the switch is {step['norm']:.3g} mg" in cal.stdout

    applied = _ok("apply", "c.json", "s.csv", "--out", "out.csv", cwd=tmp_path)
    assert f"the step at the switch is {step['norm']:.3g} mg" in applied.stdout
    d = pl.read_csv(tmp_path / "out.csv")
    assert d.columns == ["t", "ax", "ay", "az", "gx", "gy", "gz", "a2x", "a2y", "a2z", "g2x",
                         "g2y", "g2z", "acx", "acy", "acz"]
    t = d["t"].to_numpy()
    ideal, rate, still = _truth(t, seed, 3.0)
    a, a2, ac = _xyz(d, "a"), _xyz(d, "a2"), _xyz(d, "ac")
    # The second triad in the first's frame: its calibration's error within 2.5 mg on the still
    # poses (without its rotation, 3 deg: 52 mg), its samples within its noise elsewhere.
    assert _block_error_mg(a2, ideal, t, seed) < 2.5
    assert _block_error_mg(a2 @ R, ideal, t, seed) > 30
    # Its gyroscope too, turned into the reference's frame (3 deg of a 3 rad/s turn: 0.16).
    moving = ~still
    g2 = _xyz(d, "g2")
    assert np.sqrt(np.mean(np.sum((g2 - rate)[moving] ** 2, axis=1))) < 0.02
    assert np.sqrt(np.mean(np.sum((g2 @ R - rate)[moving] ** 2, axis=1))) > 0.04
    # Beyond 2.2 g the low-range triad is clipped (hundreds of mg off); the combined one is
    # the high-range triad's, within its noise (6 mg per axis: 10.4 per vector).
    big = np.linalg.norm(ideal, axis=1) > 2.2
    assert big.sum() > 100
    err = np.linalg.norm(ac - ideal, axis=1)[big] * 1e3
    assert np.sqrt(np.mean(err**2)) < 14
    assert np.sqrt(np.mean((np.linalg.norm(a - ideal, axis=1)[big] * 1e3) ** 2)) > 100
    # Well below the limit it is the low-range triad's, to the bit.
    calm = np.max(np.abs(pl.read_csv(tmp_path / "s.csv").select(["ax", "ay", "az"])
                         .to_numpy()), axis=1) < 1.5
    np.testing.assert_array_equal(ac[calm], a[calm])


def test_temperature_applied_at_each_sample_and_passed_through(tmp_path: Path):
    seed = 2
    _ok("synth", "w.csv", "--seed", str(seed), "--poses", str(POSES), "--acc2", "8",
        "--temperature", "15", "45", cwd=tmp_path)
    truth = json.loads((tmp_path / "w.csv.truth.json").read_text())["temperature"]
    assert truth["start_degC"] == 15 and truth["end_degC"] == 45 and truth["steps"] == 0
    _ok("calibrate", "w.csv", "--out", "w.json", "--all-imus", "--temperature", cwd=tmp_path)
    data = json.loads((tmp_path / "w.json").read_text())
    assert "combined" not in data["triads"]  # one range, nothing clipped: not a pair
    out = _ok("apply", "w.json", "w.csv", "--out", "w_out.csv", cwd=tmp_path)
    assert "acc a: bias at each sample's temperature (temp)" in out.stdout
    assert "held at its end values (never extrapolated)" in out.stdout
    # The same file without its temperature models: the constant calibration.
    for entry in [data, *data["triads"]["triads"]]:
        entry.pop("temperature", None)
    (tmp_path / "flat.json").write_text(json.dumps(data))
    _ok("apply", "flat.json", "w.csv", "--out", "flat.csv", cwd=tmp_path)
    d, flat = pl.read_csv(tmp_path / "w_out.csv"), pl.read_csv(tmp_path / "flat.csv")
    raw = pl.read_csv(tmp_path / "w.csv")
    np.testing.assert_array_equal(d["temp"].to_numpy(), raw["temp"].to_numpy())
    t = d["t"].to_numpy()
    ideal, _, _ = _truth(t, seed, 0.0)
    with_t = _block_error_mg(_xyz(d, "a"), ideal, t, seed)
    without = _block_error_mg(_xyz(flat, "a"), ideal, t, seed)
    assert with_t < 3.0 and with_t < 0.6 * without, (with_t, without)
    # A .mat holds each triad as one variable on t_acc, and the temperature.
    _ok("apply", "w.json", "w.csv", "--out", "w_out.mat", cwd=tmp_path)
    m = loadmat(tmp_path / "w_out.mat")
    np.testing.assert_array_equal(m["a2"], _xyz(d, "a2"))
    np.testing.assert_array_equal(m["temp"][:, 0], d["temp"].to_numpy())


def test_reference_chosen_on_calibrate_and_apply(tmp_path: Path):
    seed = 1
    _ok("synth", "s.csv", "--seed", str(seed), "--poses", str(POSES), "--acc2", "8",
        "--gyro2", cwd=tmp_path)
    R = np.array(json.loads((tmp_path / "s.csv.truth.json").read_text())
                 ["triads"][0]["rotation_to_reference"])
    _ok("calibrate", "s.csv", "--out", "a.json", "--all-imus", cwd=tmp_path)
    _ok("calibrate", "s.csv", "--out", "a2.json", "--all-imus", "--reference", "a2",
        cwd=tmp_path)
    second = json.loads((tmp_path / "a2.json").read_text())
    assert second["triads"]["reference"].startswith("acc a2 ")
    assert [e["accelerometer"] for e in second["triads"]["triads"]] == ["acc a"]
    _ok("apply", "a2.json", "s.csv", "--out", "by_file.csv", cwd=tmp_path)
    _ok("apply", "a.json", "s.csv", "--out", "by_flag.csv", "--reference", "a2", cwd=tmp_path)
    for name in ("by_file.csv", "by_flag.csv"):
        d = pl.read_csv(tmp_path / name)
        t = d["t"].to_numpy()
        ideal, rate, still = _truth(t, seed, 0.0)
        in_a2 = ideal @ R  # R' u row by row: the second triad's frame
        for prefix in ("a", "a2"):  # every triad in the second's frame, named as the table's
            assert _block_error_mg(_xyz(d, prefix), in_a2, t, seed) < 3.0, (name, prefix)
        assert _block_error_mg(_xyz(d, "a"), ideal, t, seed) > 30
        g = _xyz(d, "g")
        assert np.sqrt(np.mean(np.sum((g - rate @ R)[~still] ** 2, axis=1))) < 0.02
    bad = _imucal("calibrate", "s.csv", "--out", "x.json", "--all-imus", "--reference", "a9",
                  cwd=tmp_path)
    assert bad.returncode == 1 and not (tmp_path / "x.json").exists()
    assert bad.stderr.strip().splitlines() == [
        "imucal: error: s.csv: --reference: no accelerometer triad 'a9'; the session has: a, a2"]
    bad = _imucal("apply", "a.json", "s.csv", "--out", "x.csv", "--reference", "a9",
                  cwd=tmp_path)
    assert bad.returncode == 1 and len(bad.stderr.strip().splitlines()) == 1
    assert "no accelerometer triad 'a9' in the calibration; it holds: a, a2" in bad.stderr
    _ok("calibrate", "s.csv", "--out", "one.json", cwd=tmp_path)
    bad = _imucal("apply", "one.json", "s.csv", "--out", "x.csv", "--reference", "a2",
                  cwd=tmp_path)
    assert bad.returncode == 1 and "it holds one" in bad.stderr
    assert not (tmp_path / "x.csv").exists()


def test_synth_triad_options_refused_where_they_cannot_be_written(tmp_path: Path):
    for args, says in ((("x.mat", "--acc2", "8"), "name OUT.csv"),
                       (("x.csv", "--gyro2"), "give --acc2 too"),
                       (("x.csv", "--temp-steps", "3"), "give --temperature START END"),
                       (("x.csv", "--acc2", "8", "--acc-unit", "counts"), "not counts")):
        proc = _imucal("synth", *args, cwd=tmp_path)
        assert proc.returncode == 2 and says in proc.stderr, proc.stderr
    assert not list(tmp_path.iterdir())


def test_ranges_stated_when_nothing_clips(tmp_path: Path):
    _ok("synth", "s.csv", "--seed", "4", "--poses", str(POSES), "--acc2", "8", cwd=tmp_path)
    _ok("calibrate", "s.csv", "--out", "plain.json", "--all-imus", cwd=tmp_path)
    assert "combined" not in json.loads((tmp_path / "plain.json").read_text())["triads"]
    out = _ok("calibrate", "s.csv", "--out", "c.json", "--all-imus", "--range", "a2=8",
              "--range", "a=2", cwd=tmp_path)
    c = json.loads((tmp_path / "c.json").read_text())["triads"]["combined"]
    assert (c["low_range"], c["high_range"]) == ("acc a", "acc a2")
    assert c["low_range_limits_raw"] == {"lo": [-2.0] * 3, "hi": [2.0] * 3, "how": "stated"}
    assert c["step_at_switch_mg"] is None and "is not measured" in out.stdout
    _ok("apply", "c.json", "s.csv", "--out", "o.csv", cwd=tmp_path)
    d = pl.read_csv(tmp_path / "o.csv")
    np.testing.assert_array_equal(_xyz(d, "ac"), _xyz(d, "a"))  # 1 g: far below 2 g
    bad = _imucal("calibrate", "s.csv", "--out", "x.json", "--all-imus", "--range", "a7=2",
                  cwd=tmp_path)
    assert bad.returncode == 1 and bad.stderr.strip().splitlines() == [
        "imucal: error: s.csv: --range: no calibrated accelerometer triad 'a7'; there are: a, a2"]
