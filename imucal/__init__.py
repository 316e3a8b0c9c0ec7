"""imucal: calibrate a MEMS IMU's accelerometer and gyroscope from an ordinary recording.

The core is pure computation (it never imports rerun). Public API::

    session = imucal.load_session("session.mat")
    result = imucal.calibrate(session)            # -> Result
    imucal.save_calibration(result, "calib.json")
    calibrated = imucal.load_calibration("calib.json").apply(session)
"""

from .calibration import CalibratedSignals, Calibration
from .calibration_file import load_calibration, save_calibration
from .errors import ImucalError
from .pipeline import Result, Settings, calibrate
from .session import Session


def load_session(*args, **kwargs) -> Session:
    """Load a recording (see :func:`imucal.load.load_session`)."""
    from .load import load_session as _load

    return _load(*args, **kwargs)


__all__ = ["CalibratedSignals", "Calibration", "ImucalError", "Result", "Session", "Settings",
           "calibrate", "load_calibration", "load_session", "save_calibration"]
