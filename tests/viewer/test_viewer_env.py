"""The viewer tests on a machine without a software renderer: skipped with the package to
install on a developer's machine, failed in CI (``tests/viewer_env.py``).

The Vulkan loader reads only the driver manifests named in ``VK_DRIVER_FILES`` when it is set,
so pointing it at a file that does not exist is a machine without a Vulkan driver.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _run_native_test(tmp_path: Path, **env: str) -> subprocess.CompletedProcess:
    clean = {k: v for k, v in os.environ.items()
             if k not in ("CI", "IMUCAL_REQUIRE_VIEWER", "VK_ICD_FILENAMES", "PYTEST_ADDOPTS")}
    clean.update(VK_DRIVER_FILES=str(tmp_path / "no-such-driver.json"), **env)
    return subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-rs", "-p", "no:cacheprovider",
         "tests/viewer/test_viewer_screens.py"
         "::test_native_viewer_every_panel_of_every_tab_draws_data[sample]"],
        cwd=ROOT, env=clean, capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("ci", ["", "true"])
def test_missing_renderer_skips_with_the_package_or_fails_in_ci(tmp_path, ci):
    out = _run_native_test(tmp_path, CI=ci)
    text = out.stdout + out.stderr
    assert "install mesa-vulkan-drivers" in text, text[-2000:]
    if ci:
        assert out.returncode == 1 and ("1 error" in text or "1 failed" in text), text[-2000:]
        assert "viewer test cannot run in CI" in text
    else:
        assert out.returncode == 0 and "1 skipped" in text, text[-2000:]
