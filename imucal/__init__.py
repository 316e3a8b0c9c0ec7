"""imucal: calibrate a MEMS IMU's accelerometer and gyroscope from an ordinary recording.

The core is pure computation (it never imports rerun). Public API::

    session = imucal.load_session("session.mat")
    result = imucal.calibrate(session)            # -> Result
    imucal.save_calibration(result, "calib.json")
    calibrated = imucal.load_calibration("calib.json").apply(session)

Names are imported on first use (PEP 562), so ``import imucal`` costs nothing until then and
``imucal --help`` stays fast. ``imucal.__version__`` is the installed package's version, read
from its metadata (whose one source is ``pyproject.toml``), so it cannot drift from it.

"method.md §3" and "(M2)" in comments cite the method document, ``docs/method.md`` in the
repository (every cited section and equation is there: tests/test_method_doc.py).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

_WHERE = {
    "CalibratedSignals": "stages.apply",
    "Calibration": "stages.apply",
    "load_calibration": "io.calibration_file",
    "save_calibration": "io.calibration_file",
    "ImucalError": "errors",
    "Result": "result",
    "Settings": "settings",
    "calibrate": "pipeline",
    "Session": "session",
    "load_session": "io.load",
}

DISTRIBUTION = "imucal-rerun"  # the name pyproject.toml installs imucal under
__version__: str  # read on first use (__getattr__ below): the installed metadata's

__all__ = ["CalibratedSignals", "Calibration", "ImucalError", "Result", "Session", "Settings",
           "__version__", "calibrate", "load_calibration", "load_session", "save_calibration"]

if TYPE_CHECKING:
    from imucal.errors import ImucalError
    from imucal.io.calibration_file import load_calibration, save_calibration
    from imucal.io.load import load_session
    from imucal.pipeline import calibrate
    from imucal.result import Result
    from imucal.session import Session
    from imucal.settings import Settings
    from imucal.stages.apply import CalibratedSignals, Calibration


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(DISTRIBUTION)
    except PackageNotFoundError:  # imported from a source tree that was never installed
        return "0+unknown"


def __getattr__(name: str) -> Any:
    if name == "__version__":
        globals()[name] = value = _version()
        return value
    if name in _WHERE:
        value = getattr(importlib.import_module(f".{_WHERE[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
