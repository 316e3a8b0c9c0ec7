"""Kalibr's IMU description: the ``imu.yaml`` noise block and the ``scale-misalignment`` model.

Kalibr's scale-misalignment model (``IccScaledMisalignedImu`` in Kalibr's IccSensors.py) goes
from the true specific force ``a_i`` and rate ``w_i`` in Kalibr's IMU frame i to the readings:

    a_meas = M_a a_i + b_a                 M_a lower triangular
    w_meas = M_g C_gyro_i w_i + A a_i + b_g  M_g lower triangular, C_gyro_i a rotation

in m/s^2 and rad/s. imucal's model goes the other way, in imucal's calibrated frame c (whose
x axis is the accelerometer's x: the upper-triangular T of M2):

    a_c = A_a (a_raw - b_a),  w_c = A_g (w_raw - b_g),  A = T K  (M2, M4)

Kalibr's lower-triangular M fixes a different frame, so the conversion rotates: with
``a_c = R a_i`` (R a rotation), ``a_meas = X R a_i + c_in b_a`` where
``X = (c_in / c_out) A_a^-1`` (c: m/s^2 per raw / calibrated unit). X R must be lower
triangular: that is the LQ decomposition ``X = L Q`` (the transpose of the QR decomposition of
``X^T``; L with a positive diagonal, Q orthogonal), so ``M_a = L`` and ``R = Q^T``. For the
gyroscope, ``w_meas = A_g^-1 R w_i + b_g`` and ``A_g^-1 R = L_g Q_g`` gives ``M_g = L_g`` and
``C_gyro_i = Q_g``. ``A`` (g-sensitivity) is zero: imucal does not model it.

Kept: the whole linear model, exactly (to rounding), in Kalibr's frame i, with ``R`` written
(``imucal.R_c_i``: ``x_c = R_c_i x_i``) so a reader can go back. Lost to Kalibr's input: the
biases (Kalibr estimates them as time-varying splines; they are written under ``imucal`` for
reference). Kalibr estimates these intrinsics itself during a camera-IMU calibration, so the
matrices are for code that applies Kalibr's model (and to compare with Kalibr's result); the
noise block is what Kalibr reads from ``--imu imu.yaml``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from imucal.errors import ImucalError
from imucal.io.exports.common import Exported, ExportInput, require_gyro_rad, si_acc_factors
from imucal.io.exports.yaml_text import Comment, Commented, comment_block, dump
from imucal.io.noise_json import KALIBR_UNITS, kalibr_block

ROSTOPIC = "/imu0"


def lq(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``x = L Q``: L lower triangular with a positive diagonal, Q orthogonal."""
    q1, r1 = np.linalg.qr(np.asarray(x, dtype=float).T)
    d = np.sign(np.diag(r1))
    d[d == 0] = 1.0
    return (d[:, None] * r1).T, (q1 * d[None, :]).T


def kalibr_intrinsics(acc_matrix: np.ndarray, gyro_matrix: np.ndarray | None,
                      ratio: float) -> dict[str, np.ndarray]:
    """M_a, M_g, C_gyro_i and R_c_i from imucal's ``A_a = T K`` and ``A_g`` (``ratio`` =
    c_in / c_out for the accelerometer)."""
    L_a, Q = lq(ratio * np.linalg.inv(acc_matrix))
    if np.linalg.det(Q) < 0:
        raise ImucalError("the accelerometer model mirrors the axes (negative determinant); "
                          "Kalibr's frame needs a rotation", field="accelerometer")
    R = Q.T  # x_c = R x_i
    out = {"M_a": L_a, "R_c_i": R}
    if gyro_matrix is not None:
        L_g, Q_g = lq(np.linalg.inv(gyro_matrix) @ R)
        if np.linalg.det(Q_g) < 0:
            raise ImucalError("the gyroscope model mirrors the axes (negative determinant)",
                              field="gyroscope")
        out |= {"M_g": L_g, "C_gyro_i": Q_g}
    return out


def noise_entries(inp: ExportInput) -> tuple[dict, list[str]]:
    """The imu.yaml noise keys (with their units as comments); missing figures as comments."""
    block, notes = kalibr_block(inp.noise)
    entries: dict = {}
    for key, unit in KALIBR_UNITS.items():
        value = block.get(key)
        if value is None:
            entries[f"#{key}"] = Comment(f"{key}: not determined by this calibration's data "
                                         f"({unit}); run 'imucal noise' on a long still "
                                         "recording and pass --noise")
        else:
            what = "continuous time" if "density" in key else "bias random walk"
            entries[key] = Commented(float(value), f"{unit}" + (f", {what}"
                                                                if key != "update_rate" else ""))
        if key == "gyroscope_random_walk":
            entries["rostopic"] = Commented(ROSTOPIC, "the IMU's ROS topic: set yours")
    return entries, notes


def export(inp: ExportInput, out: Path, segment: int | None) -> Exported:
    index, seg = inp.segment(segment, "kalibr")
    c_in, c_out = si_acc_factors(inp, "kalibr")
    require_gyro_rad(inp, "kalibr")
    k = kalibr_intrinsics(seg.acc.matrix, None if seg.gyro is None else seg.gyro.matrix,
                          c_in / c_out)
    entries, notes = noise_entries(inp)
    doc: dict = dict(entries)
    doc["model"] = "scale-misalignment"
    doc["accelerometers"] = {"M": k["M_a"]}
    if seg.gyro is not None:
        doc["gyroscopes"] = {"M": k["M_g"], "A": np.zeros((3, 3)), "C_gyro_i": k["C_gyro_i"]}
    extra = {"R_c_i": Commented(k["R_c_i"], "x_imucal = R_c_i x_kalibr (a rotation)"),
             "accelerometer_bias": Commented(seg.acc.b * c_in, "m/s^2, of a_meas (b_a)")}
    if seg.gyro is not None:
        extra["gyroscope_bias"] = Commented(seg.gyro.b, "rad/s, of w_meas (b_g)")
    extra["segment"] = index
    doc["imucal"] = extra
    angle = float(np.degrees(np.arccos(np.clip((np.trace(k["R_c_i"]) - 1) / 2, -1, 1))))
    head = ["Kalibr IMU description (imu.yaml noise block + scale-misalignment intrinsics)",
            *inp.header_lines(),
            "a_meas = M_a a_i + b_a;  w_meas = M_g C_gyro_i w_i + A a_i + b_g  (m/s^2, rad/s)",
            f"Kalibr's frame i is imucal's calibrated frame turned by {angle:.4f} deg (R_c_i)"]
    text = comment_block(head) + dump(doc)
    res = Exported(files=[(out, text)])
    res.notes += [f"scale-misalignment: exact to rounding; Kalibr's frame differs from "
                  f"imucal's by a rotation of {angle:.4f} deg (written as imucal.R_c_i)",
                  "biases: not part of Kalibr's input (it estimates them); written under imucal",
                  *[f"noise: {n}" for n in notes]]
    if seg.gyro is None:
        res.notes.append("no gyroscope model in this calibration: gyroscopes block omitted")
    if len(inp.calibration.segments) > 1:
        res.notes.append(f"segment {index} of {len(inp.calibration.segments)} only")
    return res
