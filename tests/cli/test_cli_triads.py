"""imucal calibrate --all-imus / --triad on a table with a second accelerometer (a2x, a2y, a2z):
the triads section written only when asked for (method.md §11)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import polars as pl

from imucal.stages.triads import angle_deg
from imucal.synth import SecondTriad, make_session


def _imucal(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    code = "import sys; from imucal.cli import main; sys.exit(main())"
    proc = subprocess.run([sys.executable, "-c", code, *args], cwd=cwd, capture_output=True,
                          text=True, timeout=180)
    assert "Traceback" not in proc.stderr, proc.stderr
    return proc


def test_all_imus_writes_each_triad_and_its_rotation(tmp_path: Path):
    session, truth = make_session(poses=20, seed=4, acc_rate=200.0,
                                  second_acc=SecondTriad(rate=200.0))
    a2 = session.others[0]
    n = min(len(session.t_acc), len(a2.t))
    # One table, one time column: the second triad's samples on the first's rows (its clock
    # was a fraction of a sample late; in still poses that does not matter).
    table = {"t": session.t_acc[:n]}
    for i, ax in enumerate("xyz"):
        table[f"a{ax}"] = session.acc[:n, i]
        table[f"g{ax}"] = session.gyro[:n, i]
        table[f"a2{ax}"] = a2.values[:n, i]
    pl.DataFrame(table).write_csv(tmp_path / "two.csv")
    plain = _imucal("calibrate", "two.csv", "--out", "plain.json", cwd=tmp_path)
    both = _imucal("calibrate", "two.csv", "--out", "both.json", "--all-imus", cwd=tmp_path)
    named = _imucal("calibrate", "two.csv", "--out", "named.json", "--triad", "a2",
                    cwd=tmp_path)
    missing = _imucal("calibrate", "two.csv", "--out", "x.json", "--triad", "a3", cwd=tmp_path)
    assert plain.returncode == both.returncode == named.returncode == 0, both.stderr
    assert "triads" not in json.loads((tmp_path / "plain.json").read_text())
    d = json.loads((tmp_path / "both.json").read_text())
    assert d == json.loads((tmp_path / "named.json").read_text())
    (entry,) = d["triads"]["triads"]
    assert angle_deg(np.array(entry["rotation_to_reference"]), truth.triads[0].R) < 0.05
    assert entry["agreement_mg"]["after_held_out"]["rms"] < 1.0
    assert "acc a2: turned 3.0" in both.stdout
    # The rest of the file is the one-triad run's.
    plain_d = json.loads((tmp_path / "plain.json").read_text())
    assert {k: v for k, v in d.items() if k != "triads"}.keys() == plain_d.keys()
    assert d["segments"] == plain_d["segments"]
    assert missing.returncode == 1
    assert "no other accelerometer triad 'a3'" in missing.stderr
    assert not (tmp_path / "x.json").exists()


def test_temperature_from_a_temp_column(tmp_path: Path):
    from imucal.synth import TemperatureProfile

    session, truth = make_session(poses=30, seed=2, acc_rate=200.0,
                                  temperature=TemperatureProfile())
    temp = session.others[0]
    table = {"t": session.t_acc, "temp": np.interp(session.t_acc, temp.t, temp.values[:, 0])}
    for i, ax in enumerate("xyz"):
        table[f"a{ax}"] = session.acc[:, i]
        table[f"g{ax}"] = session.gyro[:, i]
    pl.DataFrame(table).write_csv(tmp_path / "warm.csv")
    pl.DataFrame({k: v for k, v in table.items() if k != "temp"}).write_csv(tmp_path / "no.csv")
    warm = _imucal("calibrate", "warm.csv", "--out", "warm.json", "--temperature", cwd=tmp_path)
    none = _imucal("calibrate", "no.csv", "--out", "no.json", "--temperature", cwd=tmp_path)
    assert warm.returncode == 0, warm.stderr
    d = json.loads((tmp_path / "warm.json").read_text())["temperature"]
    assert d["accelerometer"]["order"] == 2 and d["gyroscope"]["order"] == 2
    lo, hi = d["accelerometer"]["span_degC"]
    assert lo < 16 and hi > 44
    assert "bias of order 2 in temperature" in warm.stdout
    assert none.returncode == 1 and "no temperature stream" in none.stderr
    assert not (tmp_path / "no.json").exists()


def test_same_device_from_three_tables(tmp_path: Path):
    from imucal.synth import TemperatureProfile, random_acc_model, random_gyro_model

    rng = np.random.default_rng(9)
    acc, gyro = random_acc_model(rng), random_gyro_model(rng)
    names = []
    for i, temp in enumerate((15.0, 30.0, 45.0)):
        session, truth = make_session(poses=20, seed=i, acc_rate=200.0, acc_truth=acc,
                                      gyro_truth=gyro,
                                      temperature=TemperatureProfile(start=temp, end=temp,
                                                                     acc=((4e-4, -3e-4, 2e-4),),
                                                                     gyro=((1e-4, 0, 0),)))
        table = {"t": session.t_acc, "temp": np.interp(session.t_acc, session.others[0].t,
                                                       session.others[0].values[:, 0])}
        for k, ax in enumerate("xyz"):
            table[f"a{ax}"] = session.acc[:, k]
            table[f"g{ax}"] = session.gyro[:, k]
        names.append(f"t{i}.csv")
        pl.DataFrame(table).write_csv(tmp_path / names[-1])
    proc = _imucal("calibrate", names[0], "--same-device", names[1], "--same-device", names[2],
                   "--out", "dev.json", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    d = json.loads((tmp_path / "dev.json").read_text())["temperature"]
    assert d["accelerometer"]["order"] == 1 and d["gyroscope"]["order"] == 1
    # The accelerometer's slope: the truth's 0.4, -0.3, 0.2 mg per deg C, within 0.02.
    np.testing.assert_allclose(d["accelerometer"]["coefficients"][1],
                               [4e-4, -3e-4, 2e-4], atol=2e-5)
    assert "from 3 sessions of one device at 15.0, 30.0, 45.0 deg C" in proc.stdout
