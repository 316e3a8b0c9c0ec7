"""The autopilots' diagonal model (PX4, ArduPilot: :mod:`imucal.io.exports.autopilot` and
:mod:`~imucal.io.exports.autopilot_triads`) from imucal's, and what it drops.

These models have a diagonal scale only. imucal's ``a = T K (a_raw - b)`` (method.md M2) becomes
``a ~ K ⊙ (a_raw - b)`` in SI units: the offsets and scales are kept, the misalignment T is
dropped (T has a unit diagonal, so nothing else changes). What that costs is computed from the
model over 2000 directions spread over the sphere (the calibration file holds the still
blocks' times, not their mean readings): the vector error ``|K ⊙ (a_raw - b) - a|`` of a still
device reading |g| in each direction, RMS and maximum, in mg. The gyroscope keeps only its
offset: its scale and misalignment are dropped, and the rate error is given in % of the rate.
"""

from __future__ import annotations

import numpy as np

from imucal.io.exports.common import fibonacci_sphere
from imucal.models import SensorModel


def diagonal_acc(model: SensorModel, c_in: float, c_out: float) -> tuple[np.ndarray, np.ndarray]:
    """(offset m/s^2, scale) of ``a_SI = scale ⊙ (a_raw_SI - offset)`` from imucal's model."""
    return model.b * c_in, model.K * c_out / c_in


def dropped_misalignment_mg(model: SensorModel, g: float, n: int = 2000
                            ) -> tuple[float, float]:
    """RMS and max over the sphere of ``|K ⊙ (a_raw - b) - a|`` for ``a = g u``, in mg."""
    a = g * fibonacci_sphere(n)
    raw = model.invert(a)
    diag = (raw - model.b) * model.K
    err = np.linalg.norm(diag - a, axis=1) / g * 1000.0
    return float(np.sqrt(np.mean(err**2))), float(err.max())


def dropped_gyro_percent(model: SensorModel, n: int = 2000) -> tuple[float, float]:
    """RMS and max over rotation directions of ``|(w_raw - b) - w| / |w|`` in %."""
    w = fibonacci_sphere(n)
    raw = model.invert(w)
    err = np.linalg.norm((raw - model.b) - w, axis=1) * 100.0
    return float(np.sqrt(np.mean(err**2))), float(err.max())
