"""What the viewer tests need from the machine, and what happens when it is missing.

The native viewer renders through Vulkan; on a machine without a GPU that means Mesa's software
renderer (lavapipe, Debian/Ubuntu package ``mesa-vulkan-drivers``). The web viewer test needs
Chromium (package ``chromium``). On a developer's fresh machine a missing piece skips the test
with a reason that names the package; in CI (``CI`` or ``IMUCAL_REQUIRE_VIEWER`` set, as
``.ci/run`` does), which installs them, a missing piece fails the test, so the viewer is always
really tested there.
"""

from __future__ import annotations

import contextlib
import ctypes.util
import glob
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

RERUN = Path(sys.executable).parent / "rerun"

# Where the Vulkan loader looks for driver manifests (the loader's documented search path).
ICD_DIRS = ("/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d", "/usr/local/share/vulkan/icd.d",
            os.path.expanduser("~/.local/share/vulkan/icd.d"))


def required() -> bool:
    """True in CI: a missing renderer or browser is a failure, not a skip."""
    return any(os.environ.get(v, "").strip().lower() not in ("", "0", "false", "no")
               for v in ("CI", "IMUCAL_REQUIRE_VIEWER"))


def vulkan_missing() -> str | None:
    """Why the native viewer cannot render here, or None when it can (a software or GPU
    Vulkan driver and the loader are present)."""
    if ctypes.util.find_library("vulkan") is None:
        return "no Vulkan loader (libvulkan.so.1): install mesa-vulkan-drivers"
    # VK_DRIVER_FILES (or its older name VK_ICD_FILENAMES) replaces the loader's search path.
    override = os.environ.get("VK_DRIVER_FILES") or os.environ.get("VK_ICD_FILENAMES")
    if override:
        manifests = [p for p in override.split(os.pathsep) if os.path.isfile(p)]
    else:
        manifests = [p for d in ICD_DIRS for p in glob.glob(os.path.join(d, "*.json"))]
    software = [p for p in manifests if "lvp" in os.path.basename(p)]
    gpu = glob.glob("/dev/dri/renderD*")
    if not software and not (manifests and gpu):
        return ("no Vulkan driver for a headless render (no GPU, no lavapipe): "
                "install mesa-vulkan-drivers")
    return None


def chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


def need(reason: str | None) -> None:
    """Skip (developer machine) or fail (CI) when ``reason`` says something is missing."""
    if reason is None:
        return
    if required():
        pytest.fail(f"viewer test cannot run in CI: {reason}", pytrace=False)
    pytest.skip(reason)


def need_rerun() -> None:
    """The ``rerun`` program (the web viewer's server too) of this environment."""
    need(None if RERUN.exists() else "the rerun executable is not in the venv "
         "(pip install -e '.[test]')")


def need_native_viewer() -> None:
    need_rerun()
    need(vulkan_missing())


def need_chromium() -> str:
    need_rerun()
    path = chromium()
    need(None if path else "no Chromium for the web viewer test: install chromium")
    return str(path)


def stop_group(proc: subprocess.Popen, timeout: float = 10.0) -> None:
    """End a process started with ``start_new_session=True`` and everything in its group
    (the ``rerun`` launcher runs the real binary as a child): SIGTERM, then SIGKILL after
    ``timeout`` seconds; where the launcher already exited, its group is killed outright."""
    if proc.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    else:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(proc.pid, signal.SIGKILL)
