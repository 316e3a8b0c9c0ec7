"""A dependency-free C header that applies imucal's whole model in firmware.

``imucal_calibrate_accelerometer(t, raw, out)`` and ``imucal_calibrate_gyroscope(t, raw, out)``
compute ``out = A (raw - b)`` with ``A = T K`` (method.md M2, M4) of the piece of time ``t``
falls in, exactly as ``imucal apply`` (:meth:`imucal.stages.apply.Calibration.apply`): segment
i over [t_start, t_end] (the first from the start of time, the last to its end), and between
two segments the parameter-wise mean of the two (method.md §2), precomputed here. Time is in
seconds on the calibration session's clock; with one segment it does not matter.

A calibrated magnetometer (calib.json's ``magnetometer``, method.md M8, one model for the whole
session) adds ``imucal_mag_M``, ``imucal_mag_b``, ``imucal_mag_R_am`` and
``imucal_calibrate_magnetometer(raw, out)``: ``out = R_am M (raw - b)`` in the field's raw unit,
in the accelerometer's calibrated frame (``R_am M`` precomputed as the piece ``imucal_mag``).

Other triads and a bias in temperature (method.md §11, §12): :mod:`imucal.io.exports.c_triads`.

Arithmetic in ``IMUCAL_REAL`` (``double`` unless defined before the include, e.g. ``float`` on
an FPU without doubles); the constants are written with 17 significant digits. C99, no
library: only ``static const`` tables and ``static inline`` functions.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from imucal.io.exports.c_pieces import piece_line, pieces_table
from imucal.io.exports.common import Exported, ExportInput, fmt_num, piece_models
from imucal.io.exports.mag import MagModel

_PRELUDE = """\
#ifndef IMUCAL_CALIBRATION_H
#define IMUCAL_CALIBRATION_H

#ifndef IMUCAL_REAL
#define IMUCAL_REAL double
#endif
typedef IMUCAL_REAL imucal_real;

/* One piece of time and its model: out = A (raw - b). */
typedef struct {
    double t_start; /* s, on the calibration session's clock */
    double t_end;
    imucal_real A[3][3];
    imucal_real b[3];
} imucal_piece;
"""

_FUNCTIONS = """\
/* The piece that holds time t: the last piece starting at or before t (the first piece
 * reaches back to the start of time, the last one on to its end). */
static inline const imucal_piece *imucal_piece_at(const imucal_piece *pieces, int n, double t)
{
    int i;
    for (i = n - 1; i > 0; --i) {
        if (t >= pieces[i].t_start) {
            return &pieces[i];
        }
    }
    return &pieces[0];
}

static inline void imucal_apply_piece(const imucal_piece *p, const imucal_real raw[3],
                                      imucal_real out[3])
{
    const imucal_real d0 = raw[0] - p->b[0], d1 = raw[1] - p->b[1], d2 = raw[2] - p->b[2];
    out[0] = p->A[0][0] * d0 + p->A[0][1] * d1 + p->A[0][2] * d2;
    out[1] = p->A[1][0] * d0 + p->A[1][1] * d1 + p->A[1][2] * d2;
    out[2] = p->A[2][0] * d0 + p->A[2][1] * d1 + p->A[2][2] * d2;
}
"""


def _function(sensor: str, name: str, unit_in: str, unit_out: str) -> list[str]:
    return [f"/* {sensor}: raw in {unit_in} -> calibrated in {unit_out}; t in seconds. */",
            f"static inline void imucal_calibrate_{sensor}(double t, const imucal_real raw[3], "
            "imucal_real out[3])",
            "{",
            f"    imucal_apply_piece(imucal_piece_at({name}_pieces, {name.upper()}_PIECES, t), "
            "raw, out);",
            "}", ""]


def _matrix(name: str, m: np.ndarray) -> str:
    rows = ", ".join("{" + ", ".join(fmt_num(v) for v in row) + "}" for row in m)
    return f"static const imucal_real {name}[3][3] = {{{rows}}};"


def _magnetometer(mag: MagModel) -> list[str]:
    R = np.eye(3) if mag.R_am is None else mag.R_am
    lines = ["/* magnetometer (method.md M8): out = R_am M (raw - b), raw and out in "
             f"{mag.unit}, out in the", " * accelerometer's calibrated frame"
             + (" (R_am not estimated: the identity, the magnetometer's own frame)"
                if mag.R_am is None else "") + "; one model for the whole session. */",
             "#define IMUCAL_HAS_MAGNETOMETER 1",
             _matrix("imucal_mag_M", mag.M),
             f"static const imucal_real imucal_mag_b[3] = "
             f"{{{', '.join(fmt_num(v) for v in mag.b)}}};",
             _matrix("imucal_mag_R_am", R),
             "static const imucal_piece imucal_mag = "
             + piece_line(-np.inf, np.inf, mag.A, mag.b).strip().rstrip(",") + ";",
             "",
             "static inline void imucal_calibrate_magnetometer(const imucal_real raw[3], "
             "imucal_real out[3])",
             "{",
             "    imucal_apply_piece(&imucal_mag, raw, out);",
             "}", ""]
    return lines


def export(inp: ExportInput, out: Path, segment: int | None) -> Exported:
    cal = inp.calibration
    segs = cal.segments
    if segment is not None:  # one segment only, if asked
        _, one = inp.segment(segment, "c")
        segs = (one,)
    head = ["/*", " * imucal calibration: out = T K (raw - b) (method.md M2, M4), as",
            " * imucal_calibrate_accelerometer / imucal_calibrate_gyroscope below.",
            *[f" * {line}" for line in inp.header_lines()],
            f" * {len(segs)} segment(s); between two segments the mean of their parameters.",
            " */", ""]
    lines = head + [_PRELUDE, *pieces_table("imucal_acc", piece_models(segs, "acc")), ""]
    has_gyro = all(s.gyro is not None for s in segs)
    if has_gyro:
        lines += [*pieces_table("imucal_gyro", piece_models(segs, "gyro")), ""]
    lines += [f"#define IMUCAL_HAS_GYROSCOPE {1 if has_gyro else 0}", "", _FUNCTIONS]
    lines += _function("accelerometer", "imucal_acc", cal.acc_unit_raw, cal.acc_unit)
    if has_gyro:
        gyro_in = cal.gyro_unit_raw or "rad/s"
        lines += _function("gyroscope", "imucal_gyro",
                           gyro_in + (" (deg/s: convert first)" if gyro_in == "rad/s" else ""),
                           "rad/s")
    mag = inp.magnetometer
    if mag is not None:
        lines += _magnetometer(mag)
    more: list[str] = []
    if inp.extras is not None:  # other triads, temperature (method.md §11, §12)
        from imucal.io.exports.c_triads import extra_lines

        extra, more = extra_lines(inp)
        lines += extra
    lines += ["#endif /* IMUCAL_CALIBRATION_H */", ""]
    notes = [f"the full model of {len(segs)} segment(s), both sensors" if has_gyro else
             f"the full model of {len(segs)} segment(s), accelerometer only",
             "exact in double precision; IMUCAL_REAL float keeps about 7 digits"]
    if mag is not None:
        notes.append(f"magnetometer: the full model M8, in {mag.unit}"
                     + (" (R_am not estimated: the identity)" if mag.R_am is None else ""))
    return Exported(files=[(out, "\n".join(lines))], notes=notes + more)
