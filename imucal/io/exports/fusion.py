"""x-io Fusion's inertial calibration model as a C header of its constants.

Fusion (``FusionCalibration.h``, ``FusionCalibrationInertial``; ``FusionModelInertial`` in
recent versions) computes ``i_c = M (s ⊙ (i_u - b))``: misalignment matrix M, sensitivity
vector s (element-wise), offset b, the same shape as imucal's ``T K (x_raw - b)``. So
``M = T``, ``s = diag(K)``, ``b = b``, with the units moved to Fusion's: its AHRS takes the
accelerometer in g and the gyroscope in degrees per second.

- Accelerometer: input in g (a raw signal in m/s^2 is read in g: offset / 9.80665) or in raw
  counts; output in g (``s`` carries 1 / 9.80665 for a calibration in m/s^2).
- Gyroscope: input in deg/s (imucal's raw rad/s, offset x 180/pi) or in raw counts; output in
  deg/s (``s`` unchanged from rad/s input, since the degree factors cancel; x 180/pi for counts).

A calibrated magnetometer (calib.json's ``magnetometer``, M8) adds Fusion's magnetic model,
``m_c = softIronMatrix (m_u - hardIronOffset)`` (``FusionCalibrationMagnetic`` /
``FusionModelMagnetic``): ``softIronMatrix = R_am M``, the rotation to the accelerometer's frame
folded in, ``hardIronOffset = b``, in the magnetometer's raw unit (Fusion's AHRS uses the
field's direction only).

Nothing is lost (same equation) except precision: Fusion's types hold float (32-bit), about 7
significant digits. One model: a calibration with several segments exports one chosen segment.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from imucal.io.exports.common import RAD, Exported, ExportInput
from imucal.models import SensorModel
from imucal.session import STANDARD_GRAVITY


def _c_float(x: float) -> str:
    text = f"{float(x):.9g}"  # 9 significant digits: every float reads back exactly
    if "e" not in text and "." not in text and "inf" not in text and "nan" not in text:
        text += ".0"
    return text + "f"


def _vector(name: str, v: np.ndarray) -> str:
    return f"static const FusionVector {name} = {{{', '.join(_c_float(x) for x in v)}}};"


def _matrix(name: str, m: np.ndarray) -> str:
    # Row-major, the element order of FusionMatrix (array[3][3] or array[9] alike).
    return (f"static const FusionMatrix {name} = {{"
            + ", ".join(_c_float(x) for x in np.asarray(m).ravel()) + "};")


def fusion_parameters(model: SensorModel, unit_in: float, out_factor: float
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(M, s, b) with Fusion's input ``i_u = x_raw / unit_in`` and output ``x * out_factor``:
    ``out_factor T K (unit_in i_u - b) = T (K unit_in out_factor) (i_u - b / unit_in)``."""
    return model.T, model.K * unit_in * out_factor, model.b / unit_in


def units(inp: ExportInput) -> dict[str, tuple[str, float, str, float]]:
    """Per sensor: (Fusion input unit, raw units per input unit, output unit, output factor)."""
    cal = inp.calibration
    acc_in = {"g": ("g", 1.0), "m/s^2": ("g", STANDARD_GRAVITY),
              "counts": ("raw counts", 1.0)}[cal.acc_unit_raw]
    acc_out = 1.0 if cal.acc_unit == "g" else 1.0 / STANDARD_GRAVITY
    gyro_in = ("raw counts", 1.0) if cal.gyro_unit_raw == "counts" else ("deg/s", RAD)
    return {"accelerometer": (acc_in[0], acc_in[1], "g", acc_out),
            "gyroscope": (gyro_in[0], gyro_in[1], "deg/s", 1.0 / RAD)}


def export(inp: ExportInput, out: Path, segment: int | None) -> Exported:
    index, seg = inp.segment(segment, "fusion")
    u = units(inp)
    lines = ["/*", " * x-io Fusion calibration constants: i_c = M (s * (i_u - b))",
             " * (FusionCalibrationInertial / FusionModelInertial).",
             *[f" * {line}" for line in inp.header_lines()]]
    body = []
    res = Exported()
    for name, model, prefix in (("accelerometer", seg.acc, "imucalAccelerometer"),
                                ("gyroscope", seg.gyro, "imucalGyroscope")):
        unit_in, per_in, unit_out, factor = u[name]
        if model is None:
            lines.append(f" * {name}: no model in this calibration (not written)")
            res.notes.append(f"{name}: no model in this calibration")
            continue
        M, s, b = fusion_parameters(model, per_in, factor)
        lines.append(f" * {name}: i_u in {unit_in}, i_c in {unit_out}")
        body += [_matrix(f"{prefix}Misalignment", M), _vector(f"{prefix}Sensitivity", s),
                 _vector(f"{prefix}Offset", b), ""]
        res.notes.append(f"{name}: input {unit_in}, output {unit_out}; same model, float "
                         "precision (about 7 digits)")
    mag = inp.magnetometer
    if mag is not None:
        lines.append(f" * magnetometer: m_c = softIronMatrix (m_u - hardIronOffset), m_u and m_c "
                     f"in {mag.unit}; softIronMatrix = R_am M"
                     + (" (R_am not estimated: M alone, the magnetometer's own frame)"
                        if mag.R_am is None else ""))
        body += [_matrix("imucalSoftIronMatrix", mag.A), _vector("imucalHardIronOffset", mag.b),
                 ""]
        res.notes.append(f"magnetometer: softIronMatrix = R_am M, hardIronOffset = b, in "
                         f"{mag.unit}; same model, float precision"
                         + ("" if mag.R_am is not None else
                            "; R_am was not estimated: the field stays in the magnetometer's "
                            "own frame"))
    if len(inp.calibration.segments) > 1:
        lines.append(f" * segment {index} of {len(inp.calibration.segments)}")
        res.notes.append(f"segment {index} of {len(inp.calibration.segments)} only")
    lines += [" */", "", "#ifndef IMUCAL_FUSION_CALIBRATION_H",
              "#define IMUCAL_FUSION_CALIBRATION_H", "", '#include "Fusion.h"', "", *body,
              "#endif", ""]
    res.files.append((out, "\n".join(lines)))
    return res
