"""imu_tk's ``.calib`` files (``CalibratedTriad_::save``/``load``): one per sensor.

imu_tk's model is imucal's: ``X' = T K (X - B)`` (Tedaldi et al. 2014; method.md M2, M4), with
T the misalignment matrix (unit diagonal), K the diagonal scale matrix and B the bias vector,
all in the raw unit. Its loader reads 21 whitespace-separated numbers: T row by row, K row by
row, then B; its saver writes each matrix's rows on lines, blank lines between. No comment is
allowed (the loader would stop at it), so the units are only in imucal's report.

Nothing is lost: the same equation with the same numbers (17 significant digits). One model per
file: a calibration with several segments exports one chosen segment.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from imucal.io.exports.common import Exported, ExportInput, fmt_num
from imucal.models import SensorModel


def triad_text(model: SensorModel) -> str:
    """The text of ``CalibratedTriad_::save``: T, K (3x3 each) and B (one number a line)."""
    def rows(m: np.ndarray) -> str:
        return "\n".join(" ".join(fmt_num(v) for v in row) for row in m)

    return (rows(model.T) + "\n\n" + rows(np.diag(model.K)) + "\n\n"
            + "\n".join(fmt_num(v) for v in model.b) + "\n\n")


def calib_paths(out: Path) -> tuple[Path, Path]:
    """``NAME_acc.calib`` and ``NAME_gyro.calib`` (imu_tk's own naming, e.g.
    test_imu_acc.calib) from ``--out NAME`` or ``NAME.calib``."""
    stem = out.name[:-len(".calib")] if out.name.endswith(".calib") else out.name
    return out.with_name(f"{stem}_acc.calib"), out.with_name(f"{stem}_gyro.calib")


def export(inp: ExportInput, out: Path, segment: int | None) -> Exported:
    index, seg = inp.segment(segment, "imu_tk")
    acc_path, gyro_path = calib_paths(out)
    cal = inp.calibration
    res = Exported()
    res.files.append((acc_path, triad_text(seg.acc)))
    res.notes.append(f"{acc_path.name}: accelerometer, X' = T K (X - B), X in "
                     f"{cal.acc_unit_raw}, X' in {cal.acc_unit}; exact (same model)")
    if seg.gyro is not None:
        res.files.append((gyro_path, triad_text(seg.gyro)))
        res.notes.append(f"{gyro_path.name}: gyroscope, X in {cal.gyro_unit_raw} (deg/s data: "
                         "convert to rad/s first), X' in rad/s; exact (same model)")
    else:
        res.notes.append("no gyroscope model in this calibration: no gyro file")
    if len(cal.segments) > 1:
        res.notes.append(f"segment {index} of {len(cal.segments)} only (imu_tk holds one model)")
    return res
