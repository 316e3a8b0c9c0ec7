"""imucal apply --mag-unit norm: mx, my, mz divided by the calibrated field's norm."""

from __future__ import annotations

import json

import numpy as np
import polars as pl

from imucal.cli import main


def test_mag_unit_norm_writes_the_field_in_units_of_its_norm(tmp_path, capsys):
    session, cal = tmp_path / "s.csv", tmp_path / "cal.json"
    assert main(["synth", str(session), "--poses", "16", "--seed", "5", "--acc-rate", "50",
                 "--still", "2", "--move", "1.5", "--mag-rate", "25", "--mag-field",
                 "0.45"]) == 0
    assert main(["calibrate", str(session), "--out", str(cal)]) == 0
    field = json.loads(cal.read_text())["magnetometer"]["field"]
    assert abs(field - 0.45) < 2e-3
    plain, norm = tmp_path / "plain.csv", tmp_path / "norm.csv"
    assert main(["apply", str(cal), str(session), "--out", str(plain)]) == 0
    capsys.readouterr()
    assert main(["apply", str(cal), str(session), "--out", str(norm), "--mag-unit",
                 "norm"]) == 0
    assert "magnetometer (mx, my, mz) in units of the calibrated field" in capsys.readouterr().out
    a = pl.read_csv(plain).drop_nulls().select("mx", "my", "mz").to_numpy()
    b = pl.read_csv(norm).drop_nulls().select("mx", "my", "mz").to_numpy()
    assert len(a) == len(b) > 1000
    np.testing.assert_allclose(b * field, a, rtol=1e-9)
    n = np.linalg.norm(b, axis=1)
    # unit norm up to the noise: 0.002 gauss of 0.45 per axis
    assert abs(np.mean(n) - 1) < 1e-3 and 0.003 < np.std(n) < 0.006
    # the other columns are the same
    same = pl.read_csv(plain).select("ax", "gz").to_numpy()
    np.testing.assert_array_equal(same, pl.read_csv(norm).select("ax", "gz").to_numpy())
    # a calibration without the field cannot normalise: one line, exit 1
    data = json.loads(cal.read_text())
    del data["magnetometer"]["field"]
    (tmp_path / "nofield.json").write_text(json.dumps(data))
    assert main(["apply", str(tmp_path / "nofield.json"), str(session), "--out",
                 str(tmp_path / "x.csv"), "--mag-unit", "norm"]) == 1
    err = capsys.readouterr().err
    assert "states no field norm" in err and "Traceback" not in err
    assert main(["apply", str(cal), str(session), "--out", str(tmp_path / "y.csv"),
                 "--mag-unit", "tesla"]) == 2
