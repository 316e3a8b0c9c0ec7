"""Flight-controller parameter files: PX4 (``CAL_ACC0_*``, ``CAL_GYRO0_*``) and ArduPilot
(``INS_ACCOFFS_*``, ``INS_ACCSCAL_*``, ``INS_GYROFFS_*``).

Both apply, in the sensor's frame, offset first and then a per-axis scale:

- PX4 (``sensor_calibration/Accelerometer.hpp``, ``Correct``):
  ``a = R_board ((a_m - thermal - offset) ⊙ scale)``; ``CAL_ACC0_xOFF`` in m/s^2,
  ``CAL_ACC0_xSCALE`` dimensionless; gyroscope ``w = R_board (w_m - thermal - CAL_GYRO0_xOFF)``,
  offsets in rad/s, no scale.
- ArduPilot (``AP_InertialSensor_Backend::_rotate_and_correct_accel``): after the sensor's
  orientation, ``accel -= INS_ACCOFFS; accel *= INS_ACCSCAL`` (m/s^2, dimensionless);
  gyroscope ``gyro -= INS_GYROFFS`` (rad/s), no scale.

These models have a diagonal scale only: imucal's ``a = T K (a_raw - b)`` becomes
``a ~ K ⊙ (a_raw - b)`` in SI units, the gyroscope keeps only its offset, and what dropping the
rest costs is said in mg and % of the rate (:mod:`imucal.io.exports.diagonal`, which states how).
Both autopilots re-estimate gyroscope offsets at start-up, so those values are a starting point.

Several triads (method.md §11) or a bias in temperature (§12): one instance per IMU and the
thermal parameters, in :mod:`imucal.io.exports.autopilot_triads` and :mod:`thermal`.

A calibrated magnetometer adds ArduPilot's ``COMPASS_OFS/DIA/ODI/ORIENT`` and PX4's
``CAL_MAG0_*`` (:mod:`imucal.io.exports.mag`, where the targets' equations are stated).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from imucal.io.exports.common import (
    Exported,
    ExportInput,
    fmt_num,
    require_gyro_rad,
    si_acc_factors,
)
from imucal.io.exports.diagonal import diagonal_acc, dropped_gyro_percent, dropped_misalignment_mg
from imucal.io.exports.mag import ardupilot_mag, px4_mag


def _losses(inp: ExportInput, seg) -> list[str]:
    rms, mx = dropped_misalignment_mg(seg.acc, inp.calibration.g)
    notes = [f"accelerometer: diagonal scale only; dropping the misalignment leaves {rms:.3g} "
             f"mg RMS, {mx:.3g} mg at most, on a still device (computed from the model over "
             "2000 directions on the sphere)"]
    if seg.gyro is not None:
        grms, gmx = dropped_gyro_percent(seg.gyro)
        notes.append(f"gyroscope: offsets only; dropping its scale and misalignment leaves "
                     f"{grms:.3g} % of the rate RMS, {gmx:.3g} % at most (over directions)")
    return notes


def px4(inp: ExportInput, out: Path, segment: int | None) -> Exported:
    """A QGroundControl parameter file (tab-separated: vehicle, component, name, value, type;
    type 9 = float)."""
    if inp.extras is not None:  # several triads or temperature: one instance per IMU
        from imucal.io.exports.autopilot_triads import px4 as px4_instances

        return px4_instances(inp, out, segment)
    index, seg = inp.segment(segment, "px4")
    c_in, c_out = si_acc_factors(inp, "px4")
    require_gyro_rad(inp, "px4")
    off, scale = diagonal_acc(seg.acc, c_in, c_out)
    notes = _losses(inp, seg)
    mag = px4_mag(inp.magnetometer) if inp.magnetometer is not None else None
    if mag is not None:
        notes += mag.notes
    lines = [f"# {h}" for h in ["PX4 parameters: a = (a_m - CAL_ACC0_xOFF) * CAL_ACC0_xSCALE "
                                "(m/s^2, sensor frame); w = w_m - CAL_GYRO0_xOFF (rad/s)",
                                *inp.header_lines(), *notes,
                                *(mag.comments if mag is not None else []),
                                "set CAL_ACC0_ID / CAL_GYRO0_ID to your sensors' device ids",
                                "Vehicle-Id Component-Id Name Value Type"]]
    rows = [(f"CAL_ACC0_{a}OFF", o) for a, o in zip("XYZ", off)]
    rows += [(f"CAL_ACC0_{a}SCALE", s) for a, s in zip("XYZ", scale)]
    if seg.gyro is not None:
        rows += [(f"CAL_GYRO0_{a}OFF", o) for a, o in zip("XYZ", seg.gyro.b)]
    lines += [f"1\t1\t{name}\t{fmt_num(v)}\t9" for name, v in rows]
    if mag is not None:  # CAL_MAG0_ROT is an INT32 parameter (type 6)
        lines += [f"1\t1\t{name}\t{int(v)}\t6" if name.endswith("_ROT") else
                  f"1\t1\t{name}\t{fmt_num(v)}\t9" for name, v in mag.rows]
    return Exported(files=[(out, "\n".join(lines) + "\n")],
                    notes=notes + _segment_note(inp, index))


def ardupilot(inp: ExportInput, out: Path, segment: int | None) -> Exported:
    """A Mission Planner / MAVProxy parameter file (``NAME,VALUE`` lines, # comments)."""
    if inp.extras is not None:  # several triads or temperature: one instance per IMU
        from imucal.io.exports.autopilot_triads import ardupilot as ardupilot_instances

        return ardupilot_instances(inp, out, segment)
    index, seg = inp.segment(segment, "ardupilot")
    c_in, c_out = si_acc_factors(inp, "ardupilot")
    require_gyro_rad(inp, "ardupilot")
    off, scale = diagonal_acc(seg.acc, c_in, c_out)
    notes = _losses(inp, seg)
    if np.any(np.abs(off) > 3.5) or np.any(np.abs(scale - 1.0) > 0.2):
        notes.append("outside ArduPilot's accepted range (|offset| <= 3.5 m/s^2, scale "
                     "0.8..1.2): it will refuse these values")
    mag = ardupilot_mag(inp.magnetometer) if inp.magnetometer is not None else None
    if mag is not None:
        notes += mag.notes
    lines = [f"# {h}" for h in ["ArduPilot parameters: accel -= INS_ACCOFFS; accel *= "
                                "INS_ACCSCAL (m/s^2, after the sensor's orientation); gyro -= "
                                "INS_GYROFFS (rad/s)", *inp.header_lines(), *notes,
                                *(mag.comments if mag is not None else [])]]
    rows = [(f"INS_ACCOFFS_{a}", o) for a, o in zip("XYZ", off)]
    rows += [(f"INS_ACCSCAL_{a}", s) for a, s in zip("XYZ", scale)]
    if seg.gyro is not None:
        rows += [(f"INS_GYROFFS_{a}", o) for a, o in zip("XYZ", seg.gyro.b)]
    if mag is not None:
        rows += mag.rows
    lines += [f"{name},{int(v)}" if name == "COMPASS_ORIENT" else f"{name},{fmt_num(v)}"
              for name, v in rows]
    return Exported(files=[(out, "\n".join(lines) + "\n")],
                    notes=notes + _segment_note(inp, index))


def _segment_note(inp: ExportInput, index: int) -> list[str]:
    n = len(inp.calibration.segments)
    return [f"segment {index} of {n} only"] if n > 1 else []
