"""What a command imports is what it uses (issue 22): scipy.optimize (~0.2 s CPU), numba (~0.15 s
with its kernels' load) and rerun are imported by the steps that need them, not by ``--help``,
opening a saved recording, loading a session, or loading and applying a calibration. Each case
runs in a fresh process."""

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SESSION = ROOT / "sample_data" / "session.mat"
HEAVY = ("numpy", "scipy", "scipy.special", "scipy.optimize", "scipy.linalg", "numba",
         "llvmlite", "rerun", "polars")


def _imported(code: str, cwd: Path) -> dict:
    """Run ``code`` in a fresh interpreter; it records ``seen[label]`` = the heavy modules
    imported so far at each point it names."""
    probe = ("import json, sys\nseen = {}\n"
             f"def mark(label): seen[label] = sorted(m for m in {HEAVY!r} if m in sys.modules)\n"
             f"{code}\nprint(json.dumps(seen))\n")
    proc = subprocess.run([sys.executable, "-c", probe], cwd=cwd, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_help_imports_none_of_the_heavy_modules(tmp_path: Path) -> None:
    seen = _imported("from imucal.cli import main\n"
                     "try:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
                     "mark('help')\n"
                     "try:\n    main(['calibrate', '--help'])\nexcept SystemExit:\n    pass\n"
                     "mark('calibrate --help')\n", tmp_path)
    assert seen == {"help": [], "calibrate --help": []}


def test_a_saved_recording_is_opened_without_numpy_or_rerun(tmp_path: Path) -> None:
    """`imucal view RUN.rrd` hands the file to the viewer program: nothing to compute. Its
    ``--save`` copy (the same path up to the launch) checks the RRF header and copies."""
    (tmp_path / "run.rrd").write_bytes(b"RRF2" + bytes(60))
    seen = _imported("from imucal.cli import main\n"
                     "assert main(['view', 'run.rrd', '--save', 'copy.rrd']) == 0\n"
                     "mark('view --save')\n", tmp_path)
    assert seen == {"view --save": []}
    assert (tmp_path / "copy.rrd").read_bytes() == (tmp_path / "run.rrd").read_bytes()


def test_loading_and_applying_import_no_fit_no_kernel_no_viewer(tmp_path: Path) -> None:
    seen = _imported(
        "import imucal\n"
        f"s = imucal.load_session({str(SESSION)!r})\n"
        "mark('load_session')\n"
        "r = imucal.calibrate(s)\n"
        "mark('calibrate')\n"
        "imucal.save_calibration(r, 'calib.json')\n", tmp_path)
    assert seen["load_session"] == ["numpy"]
    # the fits and the gyroscope's passes ran: the modules are there when needed
    assert {"scipy.optimize", "scipy.special", "numba"} <= set(seen["calibrate"])
    assert "rerun" not in seen["calibrate"] and "polars" not in seen["calibrate"]
    seen = _imported(  # a factory line's other process: apply a saved calibration
        "import imucal\n"
        "cal = imucal.load_calibration('calib.json')\n"
        "mark('load_calibration')\n"
        f"out = cal.apply(imucal.load_session({str(SESSION)!r}))\n"
        "mark('apply')\n", tmp_path)
    assert seen == {"load_calibration": ["numpy"], "apply": ["numpy"]}
