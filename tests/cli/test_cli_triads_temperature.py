"""Several triads and temperature through the command line (method.md §11, §12): a 5 deg C span
said and not extrapolated, the second IMU drifting by its own coefficients (its truth written,
its own fit), and the loader's note on a2x…, g2x…, temp true whether or not they are
calibrated."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import polars as pl

from imucal.cli.synth_triads import ACC2_TEMP, GYRO2_TEMP


def _imucal(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    code = "import sys; from imucal.cli import main; sys.exit(main())"
    proc = subprocess.run([sys.executable, "-c", code, *args], cwd=cwd, capture_output=True,
                          text=True, timeout=300)
    assert "Traceback" not in proc.stderr, proc.stderr
    assert proc.returncode == 0, proc.stderr
    return proc


def _said(out: str, start: str) -> list[str]:
    return [ln for ln in out.splitlines() if ln.startswith(start)]


def test_a_5_degC_span_is_not_extrapolated_and_said_so(tmp_path: Path):
    _imucal("synth", "n.csv", "--temperature", "28", "33", "--acc-rate", "200", "--poses", "20",
            cwd=tmp_path)
    out = _imucal("calibrate", "n.csv", "--out", "n.json", "--temperature", cwd=tmp_path).stdout
    lines = _said(out, "temperature ")
    for sensor in ("accelerometer", "gyroscope"):
        (line,) = [ln for ln in lines if f" {sensor}: the still blocks span only" in ln]
        assert re.search(r"span only 4\.[5-9] deg C \(28\.[0-2] to 3[23]\.\d\), ", line)
        assert ("under the 10 deg C that tell a slope from noise: the bias model holds for "
                "that span only and is not extrapolated (kept constant outside it); record "
                "over a wider temperature range") in line
    d = json.loads((tmp_path / "n.json").read_text())["temperature"]
    for sensor in ("accelerometer", "gyroscope"):
        lo, hi = d[sensor]["span_degC"]
        assert 4.5 < hi - lo < 5.0
    # Applied to a recording that is warmer than the span: each bias is the span's end value.
    raw = pl.read_csv(tmp_path / "n.csv")
    hot = raw.with_columns(pl.lit(45.0).alias("temp"))
    edge = raw.with_columns(pl.lit(hi).alias("temp"))
    hot.write_csv(tmp_path / "hot.csv")
    edge.write_csv(tmp_path / "edge.csv")
    said = _imucal("apply", "n.json", "hot.csv", "--out", "hot_out.csv", cwd=tmp_path).stdout
    _imucal("apply", "n.json", "edge.csv", "--out", "edge_out.csv", cwd=tmp_path)
    assert "leaves the span, where the model is held at its end values (never extrapolated)" \
        in said
    a, b = pl.read_csv(tmp_path / "hot_out.csv"), pl.read_csv(tmp_path / "edge_out.csv")
    for c in ("ax", "ay", "az", "gx", "gy", "gz"):
        np.testing.assert_array_equal(a[c].to_numpy(), b[c].to_numpy())


def test_the_second_imu_drifts_by_its_own_coefficients_and_the_notes_are_true(tmp_path: Path):
    _imucal("synth", "two.csv", "--acc2", "8", "--gyro2", "--temperature", "15", "45",
            "--acc-rate", "200", "--poses", "30", "--seed", "3", cwd=tmp_path)
    truth = json.loads((tmp_path / "two.csv.truth.json").read_text())
    assert truth["temperature"]["a2_bias_coefficients_g"] == [list(c) for c in ACC2_TEMP]
    assert truth["temperature"]["g2_bias_coefficients_rad_s"] == [list(c) for c in GYRO2_TEMP]

    plain = _imucal("calibrate", "two.csv", "--out", "plain.json", cwd=tmp_path).stdout
    both = _imucal("calibrate", "two.csv", "--out", "both.json", "--all-imus",
                   "--temperature", cwd=tmp_path).stdout
    found = {"a2x, a2y, a2z": "second accelerometer", "g2x, g2y, g2z": "second gyroscope",
             "temp": "temperature"}
    for roles, label in found.items():
        head = f"  - {label} found beside the pair ({roles}: "
        (line,) = [ln for ln in plain.splitlines() if ln.startswith(head)]
        assert line.endswith("; recorded, not calibrated")
        (line,) = [ln for ln in both.splitlines() if ln.startswith(head)]
        assert "not calibrated" not in line
    assert "recorded, not calibrated" not in both
    assert "calibrated as a triad of its own and turned to the reference (the triads " \
        "section)" in both
    assert "calibrated with a2, its IMU's accelerometer (the triads section)" in both
    messages = [w["message"] for w in json.loads((tmp_path / "both.json").read_text())
                ["warnings"]]
    assert any(m.endswith("each bias a polynomial in it (the temperature section)")
               for m in messages)

    # Each triad's own fit: the second's bias follows its own truth, not the first's.
    d = json.loads((tmp_path / "both.json").read_text())
    (tri,) = d["triads"]["triads"]
    fit, t2 = tri["temperature"], truth["triads"][0]
    for sensor, b_true, coefs in (("accelerometer", t2["b"], ACC2_TEMP),
                                  ("gyroscope", t2["gyroscope"]["b"], GYRO2_TEMP)):
        f = fit[sensor]
        grid = np.linspace(*f["span_degC"], 61)
        x = np.clip(grid, *f["span_degC"]) - f["reference_degC"]
        model = np.asarray(f["b0"]) + sum(np.outer(x**j, c) for j, c in
                                          enumerate(f["coefficients"]))
        dt = grid - truth["temperature"]["reference_degC"]
        want = np.asarray(b_true) + sum(np.outer(dt ** (j + 1), c) for j, c in enumerate(coefs))
        err = np.sqrt(np.mean((model - want) ** 2))
        # Within 1 mg and 0.02 deg/s, where the first triad's drift would be several.
        assert err < (1e-3 if sensor == "accelerometer" else np.radians(0.02)), (sensor, err)

    # apply writes a2x… and g2x… calibrated and passes temp through: its notes say so.
    out = _imucal("apply", "both.json", "two.csv", "--out", "o.csv", cwd=tmp_path).stdout
    assert "second accelerometer found beside the pair (a2x, a2y, a2z: " in out
    assert "samples); calibrated, in the output's frame as a2x…" in out
    assert "samples); calibrated, in the output's frame as g2x…" in out
    assert "samples); passed through as temp" in out
    plain_out = _imucal("apply", "plain.json", "two.csv", "--out", "p.csv", cwd=tmp_path).stdout
    assert plain_out.count("; recorded, not calibrated") == 3
