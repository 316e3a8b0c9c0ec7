"""A sensor's bias in temperature (method.md §12, M16) as the flight controllers hold it.

imucal's model: ``b(T) = b0 + sum_(j=0..p) c_j (clip(T, lo, hi) - t0)^j`` in the raw unit, the
accelerometer's scales ``K (1 + k (clip(T) - t0))`` where a slope was fitted, the rest of M2 /
M4 unchanged. Both targets subtract a polynomial offset in the sensor's frame before their own
offset and scale, with the temperature clipped to the span they were given:

- PX4 (``TemperatureCompensation::calc_thermal_offsets_3D``, applied in
  ``sensor_calibration/Accelerometer.hpp`` ``Correct``: ``(data - _thermal_offset - _offset)
  .emult(_scale)``, likewise the gyroscope without a scale): ``thermal = X0 + X1 dT + X2 dT^2
  + X3 dT^3``, ``dT = clip(T, TMIN, TMAX) - TREF`` in deg C, in m/s^2 and rad/s
  (``TC_An_Xj_i``, ``TC_Gn_Xj_i``, axis i = 0, 1, 2; ``TC_A_ENABLE``/``TC_G_ENABLE`` = 1; each
  set of parameters is matched to its sensor by ``TC_An_ID``, a device id). With ``TREF = t0``,
  ``TMIN, TMAX = lo, hi``, ``Xj = c_j`` and ``CAL_ACCn_xOFF = b0`` it is imucal's b(T) exactly.
- ArduPilot (``AP_InertialSensor_tempcal.cpp``, ``TCal::correct_sensor``, called in
  ``AP_InertialSensor_Backend::_rotate_and_correct_accel`` / ``_gyro`` before ``accel -=
  offsets; accel *= scale``): ``v -= P(clip(T) - 35); v += P(clip(CALTEMP) - 35)``, clipped to
  ``[INS_TCALn_TMIN, INS_TCALn_TMAX]``, ``P(x) = (C1 + (C2 + C3 x) x) x * 1e-6`` with ``Cj`` the
  parameters ``INS_TCALn_ACCj_X/Y/Z`` (``GYRj`` for the gyroscope), stored times 1e6
  (``SCALE_FACTOR``) about a fixed 35 deg C (``TEMP_REFERENCE``: "we use a fixed reference
  temperature of 35C"); ``INS_ACCn_CALTEMP``/``INS_GYRn_CALTEMP`` is the temperature the
  offsets were set at. imucal's polynomial re-expanded about 35 deg C, ``Q(T) = d0 + P(T - 35)``,
  with ``CALTEMP = t0`` and the offset ``Q(t0) = b0 + c_0`` gives ``Q(clip(T))`` exactly.

Neither holds a slope of the scales in temperature (PX4 states that scale is assumed not to
change): what dropping it costs at the span's ends is said in mg.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from math import comb

import numpy as np

from imucal.io.exports.common import fibonacci_sphere
from imucal.stages.temperature import BiasPolynomial

AP_REFERENCE_C = 35.0  # ArduPilot's TEMP_REFERENCE
AP_SCALE = 1.0e6  # ArduPilot's SCALE_FACTOR for the INS_TCALn coefficients


def cubic(fit: BiasPolynomial, per: float = 1.0) -> np.ndarray:
    """(4, 3) the bias's offset from ``b0`` as coefficients of ``(T - t0)^j``, j = 0..3, in
    ``per`` (e.g. m/s^2) per raw unit."""
    out = np.zeros((4, 3))
    out[: len(fit.coefs)] = fit.coefs
    return out * per


def px4_rows(kind: str, n: int, fit: BiasPolynomial, per: float = 1.0
             ) -> list[tuple[str, float]]:
    """``TC_{kind}{n}_Xj_i``, ``_TREF``, ``_TMIN``, ``_TMAX`` (kind "A" or "G")."""
    c = cubic(fit, per)
    rows = [(f"TC_{kind}{n}_X{j}_{i}", c[j, i]) for j in (3, 2, 1, 0) for i in range(3)]
    return rows + [(f"TC_{kind}{n}_TREF", fit.t0), (f"TC_{kind}{n}_TMIN", fit.span[0]),
                   (f"TC_{kind}{n}_TMAX", fit.span[1])]


def about(fit: BiasPolynomial, ref: float, per: float = 1.0) -> np.ndarray:
    """(4, 3) the whole bias ``b0 + sum_j c_j (T - t0)^j`` (unclipped) re-expanded as
    ``sum_m d_m (T - ref)^m``: ``(T - t0) = (T - ref) + h``, ``h = ref - t0``, binomially."""
    a = cubic(fit)
    a[0] += fit.b0
    h = ref - fit.t0
    d = np.zeros((4, 3))
    for j in range(4):
        for m in range(j + 1):
            d[m] += a[j] * comb(j, m) * h ** (j - m)
    return d * per


@dataclass
class ArduPilotThermal:
    """One IMU's ``INS_TCALn_*`` and ``INS_ACCn_CALTEMP``/``INS_GYRn_CALTEMP`` rows, the
    offsets (SI) that go with them, and what is said."""

    rows: list[tuple[str, float]] = field(default_factory=list)
    offsets: dict[str, np.ndarray] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


def ardupilot(k: int, fits: dict[str, BiasPolynomial], per: dict[str, float]
              ) -> ArduPilotThermal:
    """IMU ``k`` (1-based, as ``INS_TCALk``): one span for both sensors (the accelerometer's
    where both have one; the gyroscope's clipped to it, and what that changes said)."""
    out = ArduPilotThermal()
    if not fits:
        return out
    span = (fits.get("accelerometer") or fits["gyroscope"]).span
    out.rows = [(f"INS_TCAL{k}_ENABLE", 1), (f"INS_TCAL{k}_TMIN", span[0]),
                (f"INS_TCAL{k}_TMAX", span[1])]
    for sensor, tag, cal in (("accelerometer", "ACC", "ACC"), ("gyroscope", "GYR", "GYR")):
        fit = fits.get(sensor)
        if fit is None:
            continue
        d = about(fit, AP_REFERENCE_C, per[sensor])
        out.rows += [(f"INS_TCAL{k}_{tag}{m}_{a}", d[m, i] * AP_SCALE)
                     for m in (1, 2, 3) for i, a in enumerate("XYZ")]
        cal_t = float(np.clip(fit.t0, *span))
        out.rows.append((f"INS_{cal}{k}_CALTEMP", cal_t))
        # the offset the polynomial is read against: Q(CALTEMP), the whole bias there
        out.offsets[sensor] = sum(d[m] * (cal_t - AP_REFERENCE_C) ** m for m in range(4))
        if fit.span != span:
            grid = np.linspace(min(span[0], fit.span[0]) - 1, max(span[1], fit.span[1]) + 1, 400)
            moved = np.abs(fit.bias_at(np.clip(grid, *span)) - fit.bias_at(grid)).max()
            unit = "deg/s" if sensor == "gyroscope" else "of the raw unit"
            size = np.degrees(moved) if sensor == "gyroscope" else moved
            out.notes.append(f"IMU {k}: one temperature span per IMU: the {sensor}'s "
                             f"({fit.span[0]:.1f}-{fit.span[1]:.1f} deg C) is clipped to "
                             f"{span[0]:.1f}-{span[1]:.1f}, its bias held up to {size:.3g} "
                             f"{unit} off outside that")
    return out


def scale_slope_loss_mg(fit: BiasPolynomial, g: float, n: int = 2000) -> float | None:
    """The most a still device's calibrated vector (``|g|`` in any of ``n`` directions) moves,
    in mg, when the scales' slope in temperature is dropped, at the span's ends; None
    without a slope."""
    if fit.scale_slope is None or fit.model is None:
        return None
    A = fit.model.matrix
    d = (g * fibonacci_sphere(n)) @ np.linalg.inv(A).T  # K(t0)-calibrated differences
    worst = 0.0
    for end in fit.span:
        change = (d * (fit.scale_slope * (end - fit.t0))) @ A.T
        worst = max(worst, float(np.linalg.norm(change, axis=1).max()) / g * 1000.0)
    return worst


def slope_note(fit: BiasPolynomial, g: float, target: str) -> list[str]:
    """One line for a scale slope the target cannot hold, or none."""
    worst = scale_slope_loss_mg(fit, g)
    if worst is None:
        return []
    ppm = ", ".join(f"{v * 1e6:+.0f}" for v in fit.scale_slope)
    return [f"accelerometer: its scales' slope in temperature ({ppm} ppm/deg C) is not held "
            f"({target} has no parameter for it): up to {worst:.3g} mg at the span's ends "
            f"({fit.span[0]:.1f} and {fit.span[1]:.1f} deg C), none at {fit.t0:.1f}"]
