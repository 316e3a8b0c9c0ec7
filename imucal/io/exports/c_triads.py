"""The C header's other triads (method.md §11) and temperature models (§12, M16).

A bias in temperature: ``imucal_thermal`` tables and ``imucal_calibrate_accelerometer_at(temp_c,
raw, out)`` (likewise ``_gyroscope_at``): ``out = A diag(1 + k x) (raw - b(T))``, ``b(T) = b0 +
c0 + c1 x + c2 x^2 + c3 x^3``, ``x = clip(T, t_min, t_max) - t0`` in deg C, ``A = T K`` of the
temperature model (for the accelerometer M17's, whose K and T the polynomial was fitted
beside); a NaN temperature gives NaN. Each other triad i (1, 2, ... in calib.json's order):
its own pieces of time (``imucal_triad{i}_acc_pieces``, as the reference's),
``imucal_triad{i}_calibrate_accelerometer(t, raw, out)`` in its own calibrated frame, its
rotation to the reference ``imucal_triad{i}_R_ref`` (M12: ``u_ref = R u``) and
``imucal_triad{i}_accelerometer_in_reference(t, raw, out)``; the gyroscope likewise (its
calibrated frame is its accelerometer's, §11), and ``_at`` functions where it has a bias in
temperature. Only written when calib.json has them: a header without is byte for byte as
before.
"""

from __future__ import annotations

import numpy as np

from imucal.io.exports.c_pieces import pieces_table  # the reference's own layout of pieces
from imucal.io.exports.common import ExportInput, fmt_num, piece_models
from imucal.io.exports.sections import TriadExport
from imucal.stages.temperature import BiasPolynomial

_THERMAL = """\
/* A sensor's model in temperature (method.md M16): out = A diag(1 + k x) (raw - b(T)),
 * b(T) = b0 + c[0] + c[1] x + c[2] x^2 + c[3] x^3, x = clip(T, t_min, t_max) - t0 (deg C). */
typedef struct {
    double t0, t_min, t_max; /* deg C: the polynomial's centre and the span it holds over */
    imucal_real A[3][3];
    imucal_real b0[3];
    imucal_real c[4][3];
    imucal_real k[3];
} imucal_thermal;

static inline void imucal_apply_thermal(const imucal_thermal *m, double temp_c,
                                        const imucal_real raw[3], imucal_real out[3])
{
    const double tc = temp_c < m->t_min ? m->t_min : (temp_c > m->t_max ? m->t_max : temp_c);
    const imucal_real x = (imucal_real)(tc - m->t0);
    imucal_real d[3];
    int i;
    for (i = 0; i < 3; ++i) {
        const imucal_real b = m->b0[i] + m->c[0][i]
            + x * (m->c[1][i] + x * (m->c[2][i] + x * m->c[3][i]));
        d[i] = (raw[i] - b) * (1 + m->k[i] * x);
    }
    out[0] = m->A[0][0] * d[0] + m->A[0][1] * d[1] + m->A[0][2] * d[2];
    out[1] = m->A[1][0] * d[0] + m->A[1][1] * d[1] + m->A[1][2] * d[2];
    out[2] = m->A[2][0] * d[0] + m->A[2][1] * d[1] + m->A[2][2] * d[2];
}
"""

_ROTATE = """\
/* A triad's calibrated vector turned into the reference triad's frame: out = R v (M12). */
static inline void imucal_to_reference(const imucal_real R[3][3], const imucal_real v[3],
                                       imucal_real out[3])
{
    out[0] = R[0][0] * v[0] + R[0][1] * v[1] + R[0][2] * v[2];
    out[1] = R[1][0] * v[0] + R[1][1] * v[1] + R[1][2] * v[2];
    out[2] = R[2][0] * v[0] + R[2][1] * v[1] + R[2][2] * v[2];
}
"""


def _vec(v) -> str:
    return "{" + ", ".join(fmt_num(x) for x in v) + "}"


def _mat(m) -> str:
    return "{" + ", ".join(_vec(row) for row in m) + "}"


def _thermal(name: str, fit: BiasPolynomial, fn: str) -> list[str]:
    c = np.zeros((4, 3))
    c[: len(fit.coefs)] = fit.coefs
    k = np.zeros(3) if fit.scale_slope is None else fit.scale_slope
    return [f"/* {fit.sensor}: bias of order {fit.order} in temperature over "
            f"{fit.span[0]:.2f}-{fit.span[1]:.2f} deg C (held at its ends outside) */",
            f"static const imucal_thermal {name} = {{{fmt_num(fit.t0)}, "
            f"{fmt_num(fit.span[0])}, {fmt_num(fit.span[1])}, {_mat(fit.model.matrix)}, "
            f"{_vec(fit.b0)}, {_mat(c)}, {_vec(k)}}};",
            f"static inline void {fn}(double temp_c, const imucal_real raw[3], "
            "imucal_real out[3])",
            "{", f"    imucal_apply_thermal(&{name}, temp_c, raw, out);", "}", ""]


def _triad(i: int, tri: TriadExport) -> list[str]:
    cal = tri.calibration
    segs = cal.segments
    p = f"imucal_triad{i}"
    R = np.eye(3) if tri.R is None else tri.R
    lines = [f"/* triad {i}: {tri.name}" + (f" with {tri.gyro}" if tri.gyro else "")
             + f"; raw {cal.acc_unit_raw} -> {cal.acc_unit}, {len(segs)} segment(s) of its own;"
             + (f" rotation to the reference {tri.angle_deg:.4g} deg */" if tri.R is not None
                else " rotation to the reference not estimated: the identity */"),
             *pieces_table(f"{p}_acc", piece_models(segs, "acc")),
             f"static const imucal_real {p}_R_ref[3][3] = {_mat(R)};", ""]
    has_gyro = all(s.gyro is not None for s in segs)
    sensors = [("accelerometer", "acc")] + ([("gyroscope", "gyro")] if has_gyro else [])
    if has_gyro:
        lines[-1:-1] = pieces_table(f"{p}_gyro", piece_models(segs, "gyro"))
    for sensor, short in sensors:
        lines += [f"static inline void {p}_calibrate_{sensor}(double t, const imucal_real "
                  "raw[3], imucal_real out[3])", "{",
                  f"    imucal_apply_piece(imucal_piece_at({p}_{short}_pieces, "
                  f"{p.upper()}_{short.upper()}_PIECES, t), raw, out);", "}",
                  f"static inline void {p}_{sensor}_in_reference(double t, const imucal_real "
                  "raw[3], imucal_real out[3])", "{", "    imucal_real v[3];",
                  f"    {p}_calibrate_{sensor}(t, raw, v);",
                  f"    imucal_to_reference({p}_R_ref, v, out);", "}", ""]
        fit = tri.temperature.get(sensor)
        if fit is not None:
            lines += _thermal(f"{p}_{short}_thermal", fit, f"{p}_calibrate_{sensor}_at")
    return lines


def extra_lines(inp: ExportInput) -> tuple[list[str], list[str]]:
    """The header's lines for the other triads (each with all its own segments) and the
    temperature models, and the notes."""
    ext = inp.extras
    if ext is None:
        return [], []
    lines: list[str] = []
    notes: list[str] = []
    fits = [*ext.temperature.values(), *(f for t in ext.triads for f in t.temperature.values())]
    if fits:
        lines += ["#define IMUCAL_HAS_TEMPERATURE 1", "", _THERMAL]
    for sensor, short in (("accelerometer", "acc"), ("gyroscope", "gyro")):
        fit = ext.temperature.get(sensor)
        if fit is not None:
            lines += _thermal(f"imucal_{short}_thermal", fit, f"imucal_calibrate_{sensor}_at")
            notes.append(f"{sensor}: its bias in temperature (order {fit.order}, "
                         f"{fit.span[0]:.1f}-{fit.span[1]:.1f} deg C) as "
                         f"imucal_calibrate_{sensor}_at(temp_c, raw, out); exact")
    if ext.triads:
        lines += [f"#define IMUCAL_TRIADS {len(ext.triads)}", "", _ROTATE]
        for i, tri in enumerate(ext.triads, start=1):
            lines += _triad(i, tri)
            notes.append(f"triad {i} ({tri.name}): its full model, its own segments, and its "
                         "rotation to the reference as imucal_triad"
                         f"{i}_accelerometer_in_reference" + (" (not estimated: the identity)"
                                                              if tri.R is None else ""))
    return lines, notes + list(ext.notes)
