"""End-to-end tests of the ``imucal`` command: the installed script, run as a subprocess."""

from __future__ import annotations

import ast
import dataclasses
import importlib.util
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import polars as pl
import pytest
from scipy.io import loadmat

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "sample_data" / "session.mat"
XSENS = ROOT.parent / "shared" / "data" / "imu_tk_xsens"
BIN = Path(sys.executable).parent
IMUCAL = shutil.which("imucal", path=str(BIN)) or str(BIN / "imucal")

pytestmark = pytest.mark.skipif(
    not Path(IMUCAL).exists(), reason=f"the imucal script is not installed beside {sys.executable}")


def _env() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if k != "IMUCAL_DEBUG"}


def run(*args, cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess:
    proc = subprocess.run([IMUCAL, *map(str, args)], cwd=cwd, capture_output=True, text=True,
                          timeout=timeout, env=_env())
    assert "Traceback" not in proc.stderr, proc.stderr
    return proc


def run_many(cases: list[list[str]], cwd: Path) -> list[subprocess.CompletedProcess]:
    """Several invocations at once (each pays the import time; they need not wait in line)."""
    procs = [subprocess.Popen([IMUCAL, *map(str, args)], cwd=cwd, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True, env=_env()) for args in cases]
    done = []
    for args, p in zip(cases, procs):
        out, err = p.communicate(timeout=120)
        assert "Traceback" not in err, err
        done.append(subprocess.CompletedProcess(args, p.returncode, out, err))
    return done


def run_python(code: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], cwd=cwd, capture_output=True, text=True,
                          timeout=120, env=_env())


def assert_one_line_error(proc: subprocess.CompletedProcess, *needles: str) -> str:
    assert proc.returncode == 1, (proc.returncode, proc.stdout, proc.stderr)
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    line = lines[0]
    assert line.startswith("imucal: error: "), line
    for needle in needles:
        assert needle in line, (needle, line)
    return line


# --- a synthetic session, calibrated once for the module ---------------------------------------


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("cli")
    proc = run("synth", "s.mat", "--poses", "30", "--seed", "3", cwd=d)
    assert proc.returncode == 0, proc.stderr
    assert (d / "s.mat").is_file() and (d / "s.mat.truth.json").is_file()
    assert "wrote s.mat" in proc.stdout
    # The installed script, run by its Python with -X importtime: which modules it loads.
    proc = subprocess.run([sys.executable, "-X", "importtime", IMUCAL, "calibrate", "s.mat",
                           "--out", "calib.json"], cwd=d, capture_output=True, text=True,
                          timeout=120, env=_env())
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    (d / "calibrate.stdout").write_text(proc.stdout)
    (d / "calibrate.importtime").write_text(proc.stderr)
    return d


def test_calibrate_recovers_the_truth(work: Path) -> None:
    calib = json.loads((work / "calib.json").read_text())
    truth = json.loads((work / "s.mat.truth.json").read_text())
    assert calib["format"] == "imucal-calibration"
    assert len(calib["segments"]) == 1
    acc, true_acc = calib["segments"][0]["accelerometer"], truth["accelerometer"]
    np.testing.assert_allclose(acc["K"], true_acc["K"], atol=3e-3)
    np.testing.assert_allclose(acc["b"], true_acc["b"], atol=3e-3)
    np.testing.assert_allclose(acc["T"], true_acc["T"], atol=3e-3)
    assert calib["quality"]["static_norm_rms_mg"]["after"] < 1.0
    assert calib["quality"]["static_norm_rms_mg"]["before"] > 5.0
    summary = (work / "calibrate.stdout").read_text()
    for text in ("verdict         good: ", "still poses", "segments", "static norm error (mg)",
                 "gravity angle (deg)", "segment 1", "wrote calib.json"):
        assert text in summary, summary


def _still_mask(t: np.ndarray, truth: dict, margin: float = 0.5) -> np.ndarray:
    mask = np.zeros(len(t), bool)
    for t0, t1 in truth["still_intervals"]:
        mask |= (t >= t0 + margin) & (t < t1 - margin)
    return mask


def test_apply_parquet(work: Path) -> None:
    proc = run("apply", "calib.json", "s.mat", "--out", "cal.parquet", cwd=work)
    assert proc.returncode == 0, proc.stderr
    raw = loadmat(work / "s.mat")
    df = pl.read_parquet(work / "cal.parquet")
    assert df.height == raw["acc"].shape[0]
    assert {"t", "ax", "ay", "az", "gx", "gy", "gz"} <= set(df.columns)
    truth = json.loads((work / "s.mat.truth.json").read_text())
    t = df["t"].to_numpy()
    acc = df.select("ax", "ay", "az").to_numpy()
    still = _still_mask(t, truth)
    norm = np.linalg.norm(acc[still], axis=1)
    assert abs(float(np.mean(norm)) - 1.0) < 2e-3
    rms = float(np.sqrt(np.mean((norm - 1.0) ** 2)))
    raw_rms = float(np.sqrt(np.mean((np.linalg.norm(raw["acc"][still], axis=1) - 1.0) ** 2)))
    assert rms < 6e-3 < 10 * rms < raw_rms, (rms, raw_rms)  # noise only, and far below the raw


@pytest.mark.parametrize("name", ["cal.csv", "cal.mat"])
def test_apply_csv_and_mat(work: Path, name: str) -> None:
    proc = run("apply", "calib.json", "s.mat", "--out", name, cwd=work)
    assert proc.returncode == 0, proc.stderr
    n = loadmat(work / "s.mat")["acc"].shape[0]
    if name.endswith(".csv"):
        acc = pl.read_csv(work / name).select("ax", "ay", "az").to_numpy()
    else:
        acc = loadmat(work / name)["acc"]
    assert acc.shape == (n, 3)
    assert abs(float(np.median(np.linalg.norm(acc, axis=1))) - 1.0) < 5e-3


def _has_module(name: str) -> bool:
    try:
        return importlib.util.find_spec(name) is not None
    except ModuleNotFoundError:
        return False


def test_calibrate_sample_data_with_calibrated_output(tmp_path: Path) -> None:
    rrd = ["--rrd", "run.rrd"] if _has_module("viewer.recording") else []
    proc = run("calibrate", SAMPLE, "--out", "c.json", "--calibrated", "c.parquet",
               "--single-segment", "--lambda", "auto", "--init", "0.5", "3", *rrd, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    if rrd:
        assert (tmp_path / "run.rrd").stat().st_size > 0 and "wrote run.rrd" in proc.stdout
    calib = json.loads((tmp_path / "c.json").read_text())
    assert calib["settings"]["single_segment"] is True
    assert calib["quality"]["static_norm_rms_mg"]["after"] < 1.0
    df = pl.read_parquet(tmp_path / "c.parquet")
    assert df.height == loadmat(SAMPLE)["acc"].shape[0]
    assert "wrote c.parquet" in proc.stdout


def test_calibrate_without_rrd_does_not_import_rerun(work: Path) -> None:
    lines = (work / "calibrate.importtime").read_text().splitlines()
    modules = [ln.rsplit("|", 1)[-1].strip() for ln in lines if ln.startswith("import time:")]
    # The log is the calibration's. (importlib.import_module, used by imucal's lazy top-level
    # names, is not timed by -X importtime; the modules pipeline imports by statement are.)
    assert "imucal.stages.accel" in modules and "imucal.stages.gyro" in modules
    bad = [m for m in modules if m.split(".")[0] in ("rerun", "rerun_bindings", "viewer")]
    assert bad == []


def test_view_save(tmp_path: Path) -> None:
    if not _has_module("viewer.app"):
        pytest.skip("viewer.app does not exist yet")
    proc = run("view", SAMPLE, "--save", "x.rrd", cwd=tmp_path, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "x.rrd").stat().st_size > 0


# --- errors: one line, the right exit code, nothing written ------------------------------------


def test_missing_file(tmp_path: Path) -> None:
    proc = run("calibrate", "nope.mat", "--out", "c.json", cwd=tmp_path)
    assert_one_line_error(proc, "nope.mat")
    assert not (tmp_path / "c.json").exists()


def test_png_renamed_mat(tmp_path: Path) -> None:
    (tmp_path / "pic.mat").write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR" + bytes(range(256)))
    proc = run("calibrate", "pic.mat", "--out", "c.json", cwd=tmp_path)
    line = assert_one_line_error(proc, "pic.mat")
    assert "format" in line
    assert not (tmp_path / "c.json").exists()


def test_csv_with_text_in_a_numeric_column(tmp_path: Path) -> None:
    rows = ["t,ax,ay,az,gx,gy,gz"] + [f"{i / 100:.2f},0,0,1,0,0,0" for i in range(400)]
    rows[123] = "1.22,0,oops,1,0,0,0"
    (tmp_path / "bad.csv").write_text("\n".join(rows) + "\n")
    proc = run("calibrate", "bad.csv", "--out", "c.json", "--calibrated", "c.csv", cwd=tmp_path)
    assert_one_line_error(proc, "bad.csv", "oops", "ay")
    assert not (tmp_path / "c.json").exists() and not (tmp_path / "c.csv").exists()


def test_output_directory_missing(work: Path) -> None:
    proc = run("calibrate", "s.mat", "--out", "no/such/dir/c.json", cwd=work)
    assert_one_line_error(proc, "does not exist")
    assert not (work / "no").exists()


def test_output_equal_to_input(work: Path) -> None:
    before = (work / "s.mat").read_bytes()
    mtime = (work / "s.mat").stat().st_mtime_ns
    cases = [["calibrate", "s.mat", "--out", "s.mat"],
             ["calibrate", "s.mat", "--out", "x.json", "--calibrated", "s.mat"],
             ["apply", "calib.json", "s.mat", "--out", "s.mat"]]
    for proc in run_many(cases, work):
        assert_one_line_error(proc, "s.mat")
    assert (work / "s.mat").read_bytes() == before
    assert (work / "s.mat").stat().st_mtime_ns == mtime
    assert not (work / "x.json").exists()


def test_malformed_calibration_file(work: Path) -> None:
    (work / "notcalib.json").write_text('{"format": "something-else"}')
    proc = run("apply", "notcalib.json", "s.mat", "--out", "never.parquet", cwd=work)
    assert_one_line_error(proc, "notcalib.json", "format")
    assert not (work / "never.parquet").exists()


USAGE_ERRORS = [
    ["--k", "abc"], ["--statistic", "median"], ["--lambda", "-1"], ["--acc-unit", "furlongs"],
    ["--columns", "ax"], ["--columns", "qx=1"], ["--init", "3", "1"], ["--window", "1"],
    ["--delta", "0"], ["--g", "-9.8"], ["--gyro-bias", "last"], ["--points", "all"],
    ["--rate", "0"], ["--time-unit", "fortnights"],
]


def test_bad_option_value_is_a_usage_error(work: Path) -> None:
    """Exit 2 from the script; then every bad value through main() in one process (fast)."""
    cases = [["calibrate", "s.mat", "--out", "bad.json", "--k", "abc"], ["calibrate", "s.mat"],
             ["synth", "bad.mat", "--poses", "1"], ["frobnicate"]]
    for args, proc in zip(cases, run_many(cases, work)):
        assert proc.returncode == 2, (args, proc.stdout, proc.stderr)
        assert "Error" in proc.stderr, (args, proc.stderr)
    more = [["calibrate", "s.mat", "--out", "bad.json", *a] for a in USAGE_ERRORS]
    more += [["apply", "calib.json", "s.mat", "--out", "bad.csv", "--gyro-unit", "rpm"],
             ["synth", "bad.mat", "--change-at", "2"], ["synth", "bad.mat", "--poses", "5",
                                                         "--minutes", "3"],
             ["view", "s.mat", "--port", "0"], ["apply", "calib.json"]]
    code = ("import contextlib, io, json, sys\nfrom imucal.cli import main\nres = []\n"
            "for args in json.loads(sys.argv[1]):\n    err = io.StringIO()\n"
            "    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):\n"
            "        rc = main(args)\n    res.append([rc, err.getvalue()])\n"
            "print(json.dumps(res))\n")
    proc = subprocess.run([sys.executable, "-c", code, json.dumps(more)], cwd=work,
                          capture_output=True, text=True, timeout=120, env=_env())
    assert proc.returncode == 0, proc.stderr
    for args, (rc, err) in zip(more, json.loads(proc.stdout)):
        assert rc == 2 and "Error" in err and "Traceback" not in err, (args, rc, err)
    for name in ("bad.json", "bad.mat", "bad.csv"):
        assert not (work / name).exists()


def test_internal_error_is_one_line(work: Path) -> None:
    code = ("import sys, imucal\n"
            "def boom(*a, **k):\n    raise RuntimeError('boom\\nsecond line')\n"
            "imucal.calibrate = boom\n"
            "from imucal.cli import main\n"
            "sys.exit(main(['calibrate', 's.mat', '--out', 'boom.json']))\n")
    proc = run_python(code, work)
    assert proc.returncode == 3, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("imucal: internal error: RuntimeError: boom")
    assert "Traceback" not in proc.stderr
    assert not (work / "boom.json").exists()


# --- speed and import discipline ---------------------------------------------------------------


def test_cli_modules_import_only_light_modules() -> None:
    """At module level the CLI imports the standard library, typer, its own modules and the
    core's error type; numpy, the viewer and the rest come inside the commands."""
    heavy = {"numpy", "scipy", "polars", "rerun", "h5py", "viewer", "pyarrow"}
    files = sorted((ROOT / "imucal" / "cli").glob("*.py"))
    assert len(files) >= 5
    for path in files:
        for node in ast.parse(path.read_text()).body:
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = [node.module or ""]
                assert node.level == 0, (path.name, ast.dump(node))
                if names[0].startswith("imucal."):
                    assert names[0].startswith("imucal.cli") or names[0] == "imucal.errors", (
                        path.name, names[0])
            for name in names:
                assert name.split(".")[0] not in heavy, (path.name, name)


def test_help_imports_nothing_heavy(tmp_path: Path) -> None:
    """`imucal --help` must stay fast: it may not import numpy, scipy, polars or rerun.
    (The time itself is measured in bench/, not asserted here.)"""
    probe = run_python("import sys, imucal.cli; "
                       "print(sorted(m for m in ('numpy', 'scipy', 'polars', 'rerun') "
                       "if m in sys.modules))", tmp_path)
    assert probe.stdout.strip() == "[]", probe.stdout + probe.stderr
    proc = run("--help", cwd=tmp_path)
    assert proc.returncode == 0 and "calibrate" in proc.stdout


def test_calibrate_plain_text_does_not_import_polars(work: Path, tmp_path: Path) -> None:
    """Plain numeric text is read by numpy: polars' import (~0.14 s CPU) is for Parquet and
    irregular text only. The files are imu_tk's kind: two aligned whitespace tables, t x y z."""
    data = loadmat(work / "s.mat")
    for sensor in ("acc", "gyro"):
        np.savetxt(tmp_path / f"{sensor}.txt", np.hstack([data[f"t_{sensor}"], data[sensor]]),
                   fmt="%15.7e", delimiter="   ")
    code = ("import sys\nfrom imucal.cli import main\n"
            "rc = main(['calibrate', 'acc.txt', '--gyro', 'gyro.txt', '--out', 'calib.json'])\n"
            "print(rc, sorted(m for m in sys.modules if m.split('.')[0] == 'polars'))\n")
    proc = run_python(code, tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == "0 []", proc.stdout + proc.stderr
    calib = json.loads((tmp_path / "calib.json").read_text())
    assert calib["quality"]["static_norm_rms_mg"]["after"] < 1.0


def test_cli_options_are_the_settings() -> None:
    """Every setting has exactly one option under its own name, and the defaults --help shows
    are the core's (init and the lambda grid are shown by their own help text)."""
    from imucal.cli.options import DEFAULTS, SETTING_OPTIONS
    from imucal.settings import Settings

    names = {name for name, _, _ in SETTING_OPTIONS} - {"init_start", "init_end"}
    assert names == {f.name for f in dataclasses.fields(Settings)}
    expected = dataclasses.asdict(Settings())
    assert DEFAULTS == expected
    for name, _, default in SETTING_OPTIONS:
        if name not in ("init", "init_start", "init_end", "lambdas"):
            assert default == expected[name], name


def test_settings_round_trip_through_calibration_file_keys() -> None:
    from imucal.settings import Settings

    s = Settings(k=5.0, init=(1.0, 4.0), lambdas=(1e-3, 1e-2, 1e-1), gyro_sensitivity=0.01)
    assert Settings.from_dict(json.loads(json.dumps(s.to_dict()))) == s


# --- real data -----------------------------------------------------------------------------------


def test_xsens_real_data(tmp_path: Path) -> None:
    if not XSENS.is_dir():
        pytest.skip("../shared/data is not beside the project")
    proc = run("calibrate", XSENS / "xsens_acc.mat", "--gyro", XSENS / "xsens_gyro.mat",
               "--out", "c.json", cwd=tmp_path, timeout=300)
    assert proc.returncode == 0, proc.stderr
    calib = json.loads((tmp_path / "c.json").read_text())
    assert calib["units"]["accelerometer_raw"] == "counts"
    assert calib["quality"]["static_norm_rms_mg"]["after"] <= 0.12


def test_main_puts_back_the_process_hooks_it_installs(tmp_path: Path) -> None:
    """An in-process run (a test, a notebook, a batch worker) keeps its own SIGTERM handler and
    warnings hook afterwards (was: every later SIGTERM became a KeyboardInterrupt)."""
    import signal
    import warnings

    from imucal.cli import main

    def mine(signum, frame):  # pragma: no cover - only identity matters
        pass

    before = signal.signal(signal.SIGTERM, mine)
    show = warnings.showwarning
    try:
        assert main(["--version"]) == 0
        assert main(["calibrate", str(tmp_path / "missing.mat"), "--out",
                     str(tmp_path / "c.json")]) == 1
        assert signal.getsignal(signal.SIGTERM) is mine
        assert warnings.showwarning is show
    finally:
        signal.signal(signal.SIGTERM, before)
