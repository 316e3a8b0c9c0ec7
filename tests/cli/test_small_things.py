"""The small things a new user trips on (issue 21, point 7; point 8's extra): each checked on
what the command does, in process where that is enough (``imucal.cli.main.main``)."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import polars as pl
import pytest
import typer

import imucal
from imucal.cli.app import app
from imucal.cli.main import main

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "sample_data" / "session.mat"
BIN = Path(sys.executable).parent
IMUCAL_VIEW = shutil.which("imucal-view", path=str(BIN)) or str(BIN / "imucal-view")
IMUCAL = shutil.which("imucal", path=str(BIN)) or str(BIN / "imucal")


def cli(capsys, *args) -> tuple[int, str, str]:
    rc = main([str(a) for a in args])
    out = capsys.readouterr()
    return rc, out.out, out.err


def one_error_line(rc: int, err: str) -> str:
    assert rc == 1, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("imucal: error: "), err
    return lines[0]


# --- usage lines and help ------------------------------------------------------------------------


def _commands(cmd, path=()):
    for name, sub in getattr(cmd, "commands", {}).items():
        yield (*path, name), sub
        yield from _commands(sub, (*path, name))


def test_usage_lines_name_arguments_without_braces(capsys):
    rc, _, err = cli(capsys, "calibrate")
    assert rc == 2 and "Usage: imucal calibrate [OPTIONS] SESSION\n" in err, err
    for path, sub in _commands(typer.main.get_command(app)):
        if getattr(sub, "commands", None):
            continue
        rc, out, _ = cli(capsys, *path, "--help")
        usage = out.splitlines()[0]
        assert rc == 0 and usage.startswith(f"Usage: imucal {' '.join(path)} "), usage
        assert "{" not in usage and "}" not in usage, usage


def test_an_xyz_option_takes_three_numbers(tmp_path, capsys):
    """synth's --drift-* and --temp-* options (imucal.cli.options.parse_triple): a usage error
    naming the option and what was given, before anything is made or written."""
    for opts, bad in ((["--activity", "walk", "--drift-acc-bias", "1,2"], "--drift-acc-bias"),
                      (["--activity", "desk", "--drift-gyro-bias", "1,2,1e7"], "--drift-gyro-bias"),
                      (["--temperature", "10", "40", "--temp-gyro-bias", "a,b,c"],
                       "--temp-gyro-bias")):
        rc, _, err = cli(capsys, "synth", tmp_path / "x.csv", *opts)
        assert rc == 2 and f"Invalid value for '{bad}': expected three numbers X,Y,Z" in err, err
    assert list(tmp_path.iterdir()) == []


def test_acc_only_help_says_what_each_command_does(capsys):
    helps = {}
    for command in ("calibrate", "apply", "noise", "inspect"):
        rc, out, _ = cli(capsys, command, "--help")
        text = " ".join(out.split())
        helps[command] = text[text.index("--acc-only"):].split(" --", 1)[0]
    assert "calibrate the accelerometer alone" in helps["calibrate"]
    assert "apply the calibration's accelerometer model alone" in helps["apply"]
    assert "measure the accelerometer's noise alone" in helps["noise"]
    assert "list what the other commands take" in helps["inspect"]
    for command in ("apply", "noise", "inspect"):
        assert "calibrate" not in helps[command], helps[command]


def test_readme_lists_every_option_of_calibrate():
    readme = (ROOT / "README.md").read_text()
    using = readme[readme.index("## Using it"):readme.index("`imucal COMMAND --help`")]
    cmd = typer.main.get_command(app).commands["calibrate"]
    flags = {o for p in cmd.params for o in p.opts + p.secondary_opts if o.startswith("--")}
    flags -= {"--help", "--no-optimise-gyro-bias", "--optimize-gyro-bias",
              "--no-optimize-gyro-bias", "--verbose"}  # the spellings of one flag; -v is listed
    missing = sorted(f for f in flags if not re.search(re.escape(f) + r"(?![\w-])", using))
    assert not missing, missing
    assert "--points ml|" in using  # the default first


# --- synth: never another session's truth ----------------------------------------------------


def test_synth_truth_is_named_after_the_whole_output_name(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    rc, out, err = cli(capsys, "synth", "my.mat", "--poses", "3", "--seed", "1")
    assert rc == 0, err
    assert "wrote my.mat.truth.json" in out
    first = (tmp_path / "my.mat.truth.json").read_bytes()
    rc, out, err = cli(capsys, "synth", "my.csv", "--poses", "3", "--seed", "2")
    assert rc == 0, err
    assert "wrote my.csv.truth.json" in out
    assert (tmp_path / "my.mat.truth.json").read_bytes() == first  # untouched
    assert not (tmp_path / "my.truth.json").exists()
    mat, csv = (json.loads((tmp_path / f"my.{e}.truth.json").read_text()) for e in ("mat", "csv"))
    assert mat["accelerometer"]["b"] != csv["accelerometer"]["b"]  # two seeds, two truths


# --- apply: one segment needs no time ------------------------------------------------------------


@pytest.fixture(scope="module")
def one_segment(tmp_path_factory) -> tuple[Path, Path, Path]:
    """A synthetic CSV session, the same without its time column, and a one-segment
    calibration of it (from Python: the verdict of the command line is not what is tested)."""
    d = tmp_path_factory.mktemp("apply")
    assert main(["synth", str(d / "s.csv"), "--poses", "14", "--seed", "4"]) == 0
    table = pl.read_csv(d / "s.csv")
    table.drop("t").write_csv(d / "notime.csv")
    result = imucal.calibrate(imucal.load_session(d / "s.csv"), single_segment=True)
    imucal.save_calibration(result, d / "c.json")
    return d / "s.csv", d / "notime.csv", d / "c.json"


def test_apply_one_segment_needs_no_rate(one_segment, tmp_path, capsys):
    _, notime, cal = one_segment
    rc, out, err = cli(capsys, "apply", cal, notime, "--out", tmp_path / "a.csv")
    assert rc == 0, err
    assert "no time column and no rate: t is the sample number" in out
    rc, _, err = cli(capsys, "apply", cal, notime, "--out", tmp_path / "b.csv", "--rate", "100")
    assert rc == 0, err
    a, b = pl.read_csv(tmp_path / "a.csv"), pl.read_csv(tmp_path / "b.csv")
    assert a["t"].to_list()[:3] == [0.0, 1.0, 2.0]
    assert b["t"].to_list()[1] == pytest.approx(0.01)
    cols = ["ax", "ay", "az", "gx", "gy", "gz"]
    assert np.array_equal(a.select(cols).to_numpy(), b.select(cols).to_numpy())
    raw = pl.read_csv(notime).select(cols).to_numpy()
    assert not np.allclose(a.select(cols).to_numpy(), raw, atol=1e-3)  # it was calibrated


def test_apply_two_segments_still_need_the_time(one_segment, tmp_path, capsys):
    _, notime, cal = one_segment
    doc = json.loads(cal.read_text())
    first, second = doc["segments"][0], json.loads(json.dumps(doc["segments"][0]))
    first["t_end"], second["t_start"] = 20.0, 30.0
    doc["segments"] = [first, second]
    two = tmp_path / "two.json"
    two.write_text(json.dumps(doc))
    rc, _, err = cli(capsys, "apply", two, notime, "--out", tmp_path / "a.csv")
    assert "--rate" in one_error_line(rc, err)
    assert not (tmp_path / "a.csv").exists()


# --- noise: the calibration's units, and no Kalibr block from a recording that moved ------------


def still_csv(path: Path, seconds: float, rate: float, density: tuple[float, float],
              gyro_deg: bool, seed: int) -> None:
    """White noise of the given densities (g/sqrt(Hz), rad/s/sqrt(Hz)) about a still pose; the
    gyroscope written in deg/s when ``gyro_deg``; no unit in the column names."""
    rng = np.random.default_rng(seed)
    n = int(seconds * rate)
    acc = rng.normal(size=(n, 3)) * density[0] * np.sqrt(rate) + [0.05, -0.1, 0.99]
    gyro = rng.normal(size=(n, 3)) * density[1] * np.sqrt(rate) + [0.01, 0.0, -0.02]
    gyro = np.degrees(gyro) if gyro_deg else gyro
    t = np.arange(n) / rate
    np.savetxt(path, np.column_stack([t, acc, gyro]), fmt="%.9g", delimiter=",",
               header="t,ax,ay,az,gx,gy,gz", comments="")


@pytest.fixture(scope="module")
def deg_calibration(tmp_path_factory) -> tuple[Path, imucal.load_calibration]:
    """A calibration fitted on a session whose gyroscope was recorded in deg/s."""
    d = tmp_path_factory.mktemp("deg")
    assert main(["synth", str(d / "s.mat"), "--gyro-unit", "deg/s", "--seed", "5"]) == 0
    result = imucal.calibrate(imucal.load_session(d / "s.mat", gyro_unit="deg/s"))
    imucal.save_calibration(result, d / "c.json")
    return d / "c.json", result


def test_recorded_units_come_from_the_calibration_file(deg_calibration, tmp_path):
    from imucal.io.calibration_file import recorded_units

    path, _ = deg_calibration
    _, units = recorded_units(path)
    assert units == {"acc_unit": "g", "gyro_unit": "deg/s"}
    doc = json.loads(path.read_text())
    assert doc["units"]["gyroscope_raw"] == "rad/s"  # the file's own unit after conversion
    doc["warnings"] = [w for w in doc["warnings"] if "deg/s" not in w["message"]]
    (tmp_path / "rad.json").write_text(json.dumps(doc))
    assert recorded_units(tmp_path / "rad.json")[1] == {"acc_unit": "g", "gyro_unit": "rad/s"}


def test_noise_with_a_calibration_reads_the_units_it_states(deg_calibration, tmp_path, capsys):
    path, result = deg_calibration
    still_csv(tmp_path / "still.csv", 120, 100.0, (2e-4, 1e-3), gyro_deg=True, seed=6)
    rc, _, err = cli(capsys, "noise", tmp_path / "still.csv")  # alone it cannot tell
    assert "give --gyro-unit" in one_error_line(rc, err)
    rc, out, err = cli(capsys, "noise", tmp_path / "still.csv", "--calibration", path,
                       "--out", tmp_path / "n.json")
    assert rc == 0, err
    assert "gyroscope read in deg/s, as c.json states" in out
    assert "accelerometer read in g, as c.json states" in out
    assert "accelerometer_noise_density: " in out  # still: the Kalibr block is given
    gyro = json.loads((tmp_path / "n.json").read_text())["noise"]["gyroscope"]
    # Calibrated in rad/s: the density through each row of T_g K_g (57 times more if the deg/s
    # had been read as rad/s).
    want = 1e-3 * np.linalg.norm(result.segments[0].gyro.model.matrix, axis=1)
    assert gyro["unit"] == "rad/s"
    assert np.allclose(gyro["white_noise_density"], want, rtol=0.15)


def test_noise_gives_no_kalibr_block_for_a_recording_that_moved(tmp_path, capsys):
    from tests.stages.test_noise_not_still import tilting_csv

    rc, _, err = cli(capsys, "noise", SAMPLE, "--gyro-unit", "rad/s")  # poses and turns
    assert "is mostly motion, not a still recording" in one_error_line(rc, err)
    SLOW = tilting_csv(tmp_path / "tilt.csv")  # still second by second, tilting over minutes
    rc, out, err = cli(capsys, "noise", SLOW, "--gyro-unit", "rad/s", "--out",
                       tmp_path / "n.json")
    assert rc == 0, err
    assert "does not look still" in out
    assert "kalibr imu.yaml  none: the recording is not still" in out
    assert "noise_density:" not in out and "update_rate:" not in out
    doc = json.loads((tmp_path / "n.json").read_text())
    assert doc["still"] is False and doc["kalibr"] is None
    rc, _, err = cli(capsys, "noise", SLOW, "--gyro-unit", "rad/s", "--kalibr",
                     tmp_path / "imu.yaml", "--out", tmp_path / "m.json")
    assert "not still" in one_error_line(rc, err)
    assert not (tmp_path / "imu.yaml").exists() and not (tmp_path / "m.json").exists()


# --- view prints the result line of calibrate -----------------------------------------------------


@pytest.mark.skipif(not Path(IMUCAL_VIEW).exists(), reason="imucal-view is not installed")
def test_view_prints_the_result_line_of_calibrate(one_segment, tmp_path):
    session, _, _ = one_segment
    runs = [subprocess.Popen(args, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True)
            for args in ([IMUCAL_VIEW, session, "--save", "v.rrd"],
                         [IMUCAL, "calibrate", session, "--out", "c.json"])]
    outs = [p.communicate(timeout=180)[0] for p in runs]
    lines = [[x for x in out.splitlines() if x.startswith("result ")] for out in outs]
    assert len(lines[0]) == 1 and lines[0] == lines[1], outs
    assert re.search(r"accelerometer \d[\d.e-]* mg held out", lines[0][0])
    assert (tmp_path / "v.rrd").is_file()


# --- the install: Dask an extra, every dependency imported --------------------------------------


def test_batch_without_dask_says_how_to_install_it(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed -> ImportError
    rc, _, err = cli(capsys, "batch", SAMPLE, "--out-dir", tmp_path / "out")
    line = one_error_line(rc, err)
    assert "pip install 'imucal-rerun[fleet]'" in line
    assert not (tmp_path / "out").exists()


# Imported by name where the distribution's name differs.
MODULE = {"rerun-sdk": "rerun", "dask": "distributed", "pyserial": "serial"}


def _dist(requirement: str) -> str:
    return re.split(r"[\[<>=!~ ;]", requirement, maxsplit=1)[0].strip()


def test_dependencies_are_imported_and_dask_is_the_fleet_extra():
    tomllib = pytest.importorskip("tomllib")  # Python 3.11 and up
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    base = {_dist(r) for r in project["dependencies"]}
    extras = {k: {_dist(r) for r in v} for k, v in project["optional-dependencies"].items()}
    assert "dask" not in base and extras["fleet"] == {"dask"}
    assert extras["fleet"] <= extras["test"]  # CI installs .[test] and runs the fleet's tests
    code = "\n".join(p.read_text() for d in ("imucal", "viewer") for p in (ROOT / d).rglob("*.py"))
    for dist in sorted(base | extras["fleet"]):
        module = MODULE.get(dist, dist)
        assert re.search(rf"^\s*(import|from) {module}\b", code, re.M), f"{dist} never imported"
    users = [p for d in ("imucal", "viewer") for p in (ROOT / d).rglob("*.py")
             if re.search(r"^\s*(import|from) distributed\b", p.read_text(), re.M)]
    assert [p.relative_to(ROOT).as_posix() for p in users] == ["imucal/fleet/batch.py"]
