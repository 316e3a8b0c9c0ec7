"""The verdict first and one numbering of segments, end to end through the installed
``imucal`` script: what a newcomer's run prints, what it writes, and what it exits with."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "sample_data" / "session.mat"
BIN = Path(sys.executable).parent
IMUCAL = shutil.which("imucal", path=str(BIN)) or str(BIN / "imucal")

pytestmark = pytest.mark.skipif(
    not Path(IMUCAL).exists(), reason=f"the imucal script is not installed beside {sys.executable}")


def run(*args, cwd: Path) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "IMUCAL_DEBUG"}
    proc = subprocess.run([IMUCAL, *map(str, args)], cwd=cwd, capture_output=True, text=True,
                          timeout=180, env=env)
    assert "Traceback" not in proc.stderr, proc.stderr
    return proc


def one_line_error(proc: subprocess.CompletedProcess) -> str:
    assert proc.returncode == 1, (proc.returncode, proc.stdout, proc.stderr)
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("imucal: error: "), proc.stderr
    return lines[0]


def test_a_useless_calibration_is_refused_unless_allowed(shared_data, tmp_path):
    """The Ferraris session (six poses): refused with its reason, nothing written; written
    with --allow-poor, its verdict in the file."""
    csv = shared_data / "imucal_ferraris" / "example_ferraris_session.csv"
    proc = run("calibrate", csv, "--rate", "102.4", "--out", "f.json", "--rrd", "f.rrd",
               cwd=tmp_path)
    line = one_line_error(proc)
    assert ("not usable: overfitted: still poses the fit did not see are off by 16.9 mg, "
            "against 0.226 mg on those it saw") in line
    assert line.endswith("nothing written (--allow-poor writes it anyway)")
    assert not (tmp_path / "f.json").exists() and not (tmp_path / "f.rrd").exists()
    assert list(tmp_path.iterdir()) == []  # no temporary left either
    out = proc.stdout.splitlines()
    assert out[0].startswith("verdict         not usable: overfitted: ")
    assert out[1].startswith("next step       record 6 more poses: with (")
    assert not any(x.startswith("wrote ") for x in out)

    proc = run("calibrate", csv, "--rate", "102.4", "--out", "f.json", "--allow-poor",
               cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines()[0] == out[0] and "wrote f.json" in proc.stdout
    verdict = json.loads((tmp_path / "f.json").read_text())["verdict"]
    assert verdict["level"] == "not usable" and verdict["code"] == "acc_held_out"
    assert out[0] == f"{'verdict':16s}not usable: {verdict['reason']}"
    # Exported anyway, the verdict is said again where the parameters leave imucal.
    proc = run("export", "f.json", "--to", "px4", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines()[0] == out[0]


def test_the_sample_says_good_first_and_keeps_the_method_behind_v(tmp_path):
    proc = run("calibrate", SAMPLE, "--out", "c.json", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout.splitlines()
    assert out[0].startswith("verdict         good: still poses the fit did not see are off by ")
    assert out[1] == "next step       none: the calibration is ready to use"
    for term in ("window 101", "Bonferroni", "L-curve", "cost reached", "M5", "M1"):
        assert term not in proc.stdout, term
    calib = json.loads((tmp_path / "c.json").read_text())
    assert calib["verdict"]["level"] == "good"
    proc = run("export", "c.json", "--to", "px4", cwd=tmp_path)
    assert proc.stdout.startswith("export          px4: c.json")  # good: nothing to add
    # The details: with -v, and in calib.json whatever is printed.
    verbose = run("calibrate", SAMPLE, "--out", "v.json", "-v", cwd=tmp_path).stdout
    assert "L-curve corner, point " in verbose and "Bonferroni" in verbose
    assert "cost reached from each start" in verbose
    assert "Bonferroni" in calib["grouping"]["mode"] and calib["lcurve"]


def test_calibrate_takes_a_spec_as_batch_does(tmp_path):
    """The sample's accelerometer bias is 76 mg on x and 49 on z: a 40 mg limit makes it not
    usable."""
    (tmp_path / "tight.toml").write_text("acc_bias_mg = 40\n")
    (tmp_path / "loose.toml").write_text("acc_bias_mg = 100\nstatic_norm_error_mg = 1\n")
    proc = run("calibrate", SAMPLE, "--out", "c.json", "--spec", "tight.toml", cwd=tmp_path)
    line = one_line_error(proc)
    assert ("not usable: out of the limits of tight.toml: acc_bias_mg: b_x = -75.77 mg (limit 40) "
            "(and 1 more)") in line  # b_z = -48.5 mg too
    assert not (tmp_path / "c.json").exists()
    proc = run("calibrate", SAMPLE, "--out", "c.json", "--spec", "loose.toml", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    spec = json.loads((tmp_path / "c.json").read_text())["verdict"]["spec"]
    assert spec["pass"] is True and spec["broken"] == [] and spec["file"] == "loose.toml"
    assert spec["limits"] == {"acc_bias_mg": 100.0, "static_norm_error_mg": 1.0}
    (tmp_path / "bad.toml").write_text("acc_bias = 40\n")
    line = one_line_error(run("calibrate", SAMPLE, "--out", "c.json", "--spec", "bad.toml",
                              cwd=tmp_path))
    assert "bad.toml: acc_bias: unknown limit" in line


@pytest.fixture(scope="module")
def two(tmp_path_factory) -> tuple[Path, str]:
    d = tmp_path_factory.mktemp("two")
    proc = run("synth", "s.mat", "--poses", "40", "--seed", "5", "--change-at", "0.5", cwd=d)
    assert proc.returncode == 0, proc.stderr
    proc = run("calibrate", "s.mat", "--out", "calib.json", cwd=d)
    assert proc.returncode == 0, proc.stderr
    return d, proc.stdout


def test_segments_are_numbered_alike_in_the_summary_the_file_and_export(two):
    """What calibrate prints as segment N is what export --segment N writes; without
    --segment a one-model export is refused with the segments and their times."""
    d, summary = two
    assert summary.startswith("verdict         good: still poses the fit did not see are off by ")
    printed = {int(n): (a, b) for n, a, b in
               re.findall(r"^segment (\d+) +(\d+\.\d)-(\d+\.\d) s", summary, re.M)}
    assert sorted(printed) == [1, 2]
    segs = json.loads((d / "calib.json").read_text())["segments"]
    for n, (a, b) in printed.items():
        assert (a, b) == (f"{segs[n - 1]['t_start']:.1f}", f"{segs[n - 1]['t_end']:.1f}")
    listed = ", ".join(f"{n} ({a}-{b} s)" for n, (a, b) in sorted(printed.items()))

    line = one_line_error(run("export", "calib.json", "--to", "px4", "--out", "p.params",
                              cwd=d))
    assert f"choose one with --segment N: {listed}" in line
    assert not (d / "p.params").exists()
    for n in (1, 2):
        proc = run("export", "calib.json", "--to", "json", "--segment", n, "--out",
                   f"seg{n}.json", cwd=d)
        assert proc.returncode == 0, proc.stderr
        (piece,) = json.loads((d / f"seg{n}.json").read_text())["pieces"]
        assert (f"{piece['t_start']:.1f}", f"{piece['t_end']:.1f}") == printed[n]
        assert piece["accelerometer"]["b"] == segs[n - 1]["accelerometer"]["b"]
    line = one_line_error(run("export", "calib.json", "--to", "px4", "--segment", "3", cwd=d))
    assert f"segment 3 does not exist; the segments are {listed}" in line
