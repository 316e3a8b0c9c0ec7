"""The tree tells the method: imports only run downward (the contracts in pyproject.toml), the
stages sit in run order, and no module grows past what one idea needs."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_imports_only_run_downward() -> None:
    exe = shutil.which("lint-imports") or str(Path(sys.executable).with_name("lint-imports"))
    if not Path(exe).exists():
        pytest.fail("lint-imports is missing: install the test extras (pip install -e '.[test]')")
    proc = subprocess.run([exe, "--config", str(ROOT / "pyproject.toml")], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-2000:]
    assert "0 broken" in proc.stdout


def test_stage_folders_hold_the_method() -> None:
    stages = {p.stem for p in (ROOT / "imucal" / "stages").glob("*.py")} - {"__init__"}
    assert {"detect", "group", "accel", "gyro", "apply", "quality"} <= stages
    numerics = (ROOT / "imucal" / "numerics").rglob("*.py")
    for path in numerics:  # numerics know nothing of IMUs
        text = path.read_text().lower()
        for word in ("accelerometer", "gyroscope", "imu"):
            assert f"import {word}" not in text and f"from imucal.{word}" not in text
