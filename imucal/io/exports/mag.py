"""The magnetometer in the exports: calib.json's ``magnetometer`` section (model M8, method.md
§9) read back and turned into each target's parameters.

imucal's model: ``m = R_am M (m_raw - b)``, ``M`` symmetric with det 1, ``b`` the hard iron,
both in the raw unit (``unit``), ``R_am`` the rotation from the magnetometer's corrected frame
to the accelerometer's calibrated frame (None when the fit had too few still blocks).

The targets' own equations (read in their source):

- ArduPilot (``AP_Compass_Backend``): the driver's field, in milligauss, is first turned by the
  orientation (``rotate_field``: ``COMPASS_ORIENT`` for an external compass), then corrected
  (``correct_field``): ``mag += COMPASS_OFS`` (offsets are *added*, in milligauss), then
  ``mag = S mag`` with ``S`` symmetric, diagonal ``COMPASS_DIA_X/Y/Z`` and off-diagonals
  ``COMPASS_ODI_X = S01, _Y = S02, _Z = S12``. So ``m_ap = S (R_o m_raw_mG + OFS)``. With
  ``R_o`` the enumerated rotation nearest ``R_am``: ``S = R_o M R_o'``, ``OFS = -c R_o b``
  (``c`` milligauss per raw unit) give ``m_ap = c R_o M (m_raw - b)``, imucal's field in
  milligauss with ``R_am`` replaced by ``R_o``: what is left is the rotation ``R_am R_o'``,
  whose angle the export states.
- PX4 (``sensor_calibration/Magnetometer``, ``Correct``): ``m = R (S (m_raw - OFF))`` in gauss,
  ``S`` symmetric, diagonal ``CAL_MAG0_xSCALE``, off-diagonals ``CAL_MAG0_XODIAG = S01,
  _YODIAG = S02, _ZODIAG = S12``, ``R`` from ``CAL_MAG0_ROT`` (external magnetometers; an
  internal one takes the board's rotation and ``CAL_MAG0_ROT = -1``). Offsets are in the sensor
  frame: ``OFF = c b``, ``S = M``, and the residual is again ``R_am R_o'``.
- Both enumerations are the MAVLink sensor orientations, ``R = Rz(yaw) Ry(pitch) Rx(roll)``
  (PX4's ``get_rot_matrix``: ``Dcmf(Eulerf(roll, pitch, yaw))``; ArduPilot's
  ``Vector3::rotate``, the same matrices written out), taking the sensor's vector to the
  vehicle's: ``R_am`` read with the accelerometer's frame as the vehicle's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from imucal.errors import ImucalError

# gauss per raw unit; counts and normalised fields have no physical unit
GAUSS = {"gauss": 1.0, "uT": 0.01, "mG": 1e-3, "T": 1e4}


@dataclass(frozen=True)
class MagModel:
    """calib.json's calibrated magnetometer: ``m = R_am M (m_raw - b)`` in ``unit``."""

    unit: str | None
    M: np.ndarray
    b: np.ndarray
    R_am: np.ndarray | None
    field: float
    dip_deg: float | None
    stream: str | None

    @property
    def A(self) -> np.ndarray:
        """``R_am M`` (``M`` alone without ``R_am``): the whole model is ``A (m_raw - b)``."""
        return self.M if self.R_am is None else self.R_am @ self.M

    @property
    def gauss(self) -> float | None:
        """Gauss per raw unit, None for counts or a normalised field."""
        return GAUSS.get(self.unit or "")


def read_mag(data: dict, path: Path) -> MagModel | None:
    """The ``magnetometer`` section of a calib.json (``data``, read from ``path``) when it says
    ``calibrated: true``; None when there is none or it was not calibrated (the export is
    then as it always was)."""
    sec = data.get("magnetometer")
    if not isinstance(sec, dict) or sec.get("calibrated") is not True:
        return None

    def arr(key: str, shape: tuple[int, ...], optional: bool = False) -> np.ndarray | None:
        v = sec.get(key)
        if v is None and optional:
            return None
        try:
            a = np.asarray(v, dtype=float)
        except (TypeError, ValueError):
            a = np.zeros(0)
        if a.shape != shape or not np.all(np.isfinite(a)):
            raise ImucalError(f"expected {'x'.join(map(str, shape))} finite numbers",
                              source=str(path), field=f"magnetometer.{key}")
        return a

    M = arr("M", (3, 3))
    b = arr("b", (3,))
    R = arr("R_am", (3, 3), optional=True)
    assert M is not None and b is not None
    if not np.allclose(M, M.T, atol=1e-9):
        raise ImucalError("expected a symmetric soft-iron matrix", source=str(path),
                          field="magnetometer.M")
    if R is not None and not (np.allclose(R @ R.T, np.eye(3), atol=1e-6)
                              and np.linalg.det(R) > 0):
        raise ImucalError("expected a rotation matrix", source=str(path),
                          field="magnetometer.R_am")
    field = sec.get("field")
    dip = sec.get("dip_deg")
    return MagModel(unit=sec.get("unit"), M=M, b=b, R_am=R,
                    field=float(field) if field is not None else float("nan"),
                    dip_deg=float(dip) if dip is not None else None, stream=sec.get("stream"))


# --- the enumerated orientations ------------------------------------------------------------------


def euler_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """``Rz(yaw) Ry(pitch) Rx(roll)``, angles in degrees."""
    r, p, y = np.radians([roll, pitch, yaw])
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


# (roll, pitch, yaw) in degrees of MAV_SENSOR_ORIENTATION 0..40, PX4's rot_lookup and
# ArduPilot's enum Rotation alike (names ROTATION_ROLL_180_YAW_45 etc.)
_COMMON = [(0, 0, 0), (0, 0, 45), (0, 0, 90), (0, 0, 135), (0, 0, 180), (0, 0, 225),
           (0, 0, 270), (0, 0, 315), (180, 0, 0), (180, 0, 45), (180, 0, 90), (180, 0, 135),
           (0, 180, 0), (180, 0, 225), (180, 0, 270), (180, 0, 315), (90, 0, 0), (90, 0, 45),
           (90, 0, 90), (90, 0, 135), (270, 0, 0), (270, 0, 45), (270, 0, 90), (270, 0, 135),
           (0, 90, 0), (0, 270, 0), (0, 180, 90), (0, 180, 270), (90, 90, 0), (180, 90, 0),
           (270, 90, 0), (90, 180, 0), (270, 180, 0), (90, 270, 0), (180, 270, 0),
           (270, 270, 0), (90, 180, 90), (90, 0, 270), (90, 68, 293), (0, 315, 0),
           (90, 315, 0)]
# ArduPilot's COMPASS_ORIENT @Values: 0..40, 42 Roll45, 43 Roll315 (41, Pitch7, is not offered)
ARDUPILOT_ORIENT = {i: e for i, e in enumerate(_COMMON)} | {42: (45, 0, 0), 43: (315, 0, 0)}
# PX4's rot_lookup: 0..40, then 41..47
PX4_ROT = {i: e for i, e in enumerate(_COMMON)} | {
    41: (270, 0, 180), 42: (270, 0, 270), 43: (0, 90, 180), 44: (0, 9, 180), 45: (0, 45, 0),
    46: (270, 0, 225), 47: (270, 0, 315)}
# ArduPilot writes its 38 out as a matrix (Vector3::rotate), not from the rounded angles
_ARDUPILOT_38 = np.array([[0.14303897231223747, 0.36877648650320383, -0.91844638134308709],
                          [-0.33213277779664740, -0.85628942146641884, -0.39554550256296522],
                          [-0.93232380121551217, 0.36162457008209242, 0.0]])


def orientation_matrix(table: dict[int, tuple[float, float, float]], code: int) -> np.ndarray:
    if table is ARDUPILOT_ORIENT and code == 38:
        return _ARDUPILOT_38
    return euler_matrix(*table[code])


def rotation_angle_deg(R: np.ndarray) -> float:
    return math.degrees(math.acos(float(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def nearest_orientation(R_am: np.ndarray, table: dict[int, tuple[float, float, float]]
                        ) -> tuple[int, np.ndarray, float]:
    """(code, its matrix, angle of ``R_am R_o'`` in degrees) of the enumerated rotation
    nearest ``R_am`` (smallest residual angle; the lowest code among equals)."""
    best = min(table, key=lambda k: (round(rotation_angle_deg(
        R_am @ orientation_matrix(table, k).T), 9), k))
    R_o = orientation_matrix(table, best)
    return best, R_o, rotation_angle_deg(R_am @ R_o.T)


# --- the targets ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Autopilot:
    """What an autopilot export adds: parameter rows, comment lines, notes (the loss said)."""

    rows: list[tuple[str, float]]
    comments: list[str]  # the target's equation, for the file's comment block
    notes: list[str]  # what was kept or lost, in the file and printed


def _no_unit(mag: MagModel, target: str, want: str) -> Autopilot:
    note = (f"magnetometer: fitted on {mag.unit or 'an unknown unit'}, and {target} takes the "
            f"field in {want}: not written (calibrate the driver's output in gauss, uT or mG)")
    return Autopilot([], [], [note])


def _residual_words(target: str, name: str, code: int, angle: float, R_am: np.ndarray) -> str:
    return (f"magnetometer: {target} has no continuous rotation: {name} = {code}, the "
            f"enumerated rotation nearest R_am (a turn of {rotation_angle_deg(R_am):.3g} deg), "
            f"leaves a residual rotation of {angle:.3g} deg between its field and imucal's "
            "(R_am R_o')")


def ardupilot_mag(mag: MagModel) -> Autopilot:
    """COMPASS_OFS/DIA/ODI (+ COMPASS_ORIENT) for ``m_ap = S (R_o m_raw_mG + OFS)``."""
    if mag.gauss is None:
        return _no_unit(mag, "ArduPilot", "milligauss")
    c = mag.gauss * 1000.0  # milligauss per raw unit
    comments = ["compass: mag = R_o mag_mG (COMPASS_ORIENT, external compass); mag += "
                "COMPASS_OFS (mG, added); mag = S mag, S = [[DIA_X, ODI_X, ODI_Y], [ODI_X, "
                "DIA_Y, ODI_Z], [ODI_Y, ODI_Z, DIA_Z]]; the field comes out in mG, |m| = "
                f"{mag.field * c:.4g} mG here; set COMPASS_MOTCT 0, COMPASS_SCALE 1"]
    if mag.R_am is None:
        R_o = np.eye(3)
        notes = ["magnetometer: calib.json holds no R_am (not estimated): COMPASS_ORIENT "
                 "not written, the offsets and matrix are for the sensor's own frame"]
        rows: list[tuple[str, float]] = []
    else:
        code, R_o, angle = nearest_orientation(mag.R_am, ARDUPILOT_ORIENT)
        notes = [_residual_words("ArduPilot", "COMPASS_ORIENT", code, angle, mag.R_am)
                 + "; COMPASS_ORIENT applies to an external compass (COMPASS_EXTERNAL 1; an "
                   "internal one takes AHRS_ORIENTATION)"]
        rows = [("COMPASS_ORIENT", float(code))]
    S = R_o @ mag.M @ R_o.T
    ofs = -c * (R_o @ mag.b)
    rows = [(f"COMPASS_OFS_{a}", o) for a, o in zip("XYZ", ofs)] + [
        (f"COMPASS_DIA_{a}", S[i, i]) for i, a in enumerate("XYZ")] + [
        (f"COMPASS_ODI_{a}", S[i, j]) for a, (i, j) in zip("XYZ", ((0, 1), (0, 2), (1, 2)))
    ] + rows
    if (np.any(np.abs(np.diag(S) - 1.0) > 0.2) or np.any(np.abs(S[np.triu_indices(3, 1)]) > 0.2)
            or np.linalg.norm(ofs) > 1800.0):
        notes.append("magnetometer: outside ArduPilot's calibrator's range (DIA 0.8..1.2, "
                     "|ODI| <= 0.2, |OFS| <= COMPASS_OFFS_MAX, 1800 mG by default)")
    return Autopilot(rows, comments, notes)


def px4_mag(mag: MagModel) -> Autopilot:
    """CAL_MAG0_xOFF/xSCALE/xODIAG (+ CAL_MAG0_ROT) for ``m = R (S (m_raw_G - OFF))``."""
    if mag.gauss is None:
        return _no_unit(mag, "PX4", "gauss")
    c = mag.gauss
    comments = ["magnetometer: m = R (S (m_G - CAL_MAG0_xOFF)) (gauss, offsets in the sensor "
                "frame), S = [[XSCALE, XODIAG, YODIAG], [XODIAG, YSCALE, ZODIAG], [YODIAG, "
                f"ZODIAG, ZSCALE]], R from CAL_MAG0_ROT; |m| = {mag.field * c:.4g} gauss here"]
    rows = [(f"CAL_MAG0_{a}OFF", o) for a, o in zip("XYZ", c * mag.b)]
    rows += [(f"CAL_MAG0_{a}SCALE", mag.M[i, i]) for i, a in enumerate("XYZ")]
    rows += [(f"CAL_MAG0_{a}ODIAG", mag.M[i, j])
             for a, (i, j) in zip("XYZ", ((0, 1), (0, 2), (1, 2)))]
    if mag.R_am is None:
        notes = ["magnetometer: calib.json holds no R_am (not estimated): CAL_MAG0_ROT "
                 "not written"]
    else:
        code, _, angle = nearest_orientation(mag.R_am, PX4_ROT)
        notes = [_residual_words("PX4", "CAL_MAG0_ROT", code, angle, mag.R_am)
                 + "; CAL_MAG0_ROT applies to an external magnetometer (an internal one "
                   "takes SENS_BOARD_ROT and -1)"]
        rows.append(("CAL_MAG0_ROT", float(code)))
    return Autopilot(rows, comments, notes)


def plain_mag(mag: MagModel) -> dict:
    """The json/yaml ``magnetometer`` entry: the model with its arrays and unit."""
    return {"model": "m = A (m_raw - b), A = R_am M (M symmetric, det 1: |m| = field; R_am "
                     "turns the magnetometer's corrected frame into the accelerometer's "
                     "calibrated frame; A = M where R_am is null), m_raw and m in unit "
                     "(method.md M8)",
            "unit": mag.unit, "A": mag.A.tolist(), "M": mag.M.tolist(), "b": mag.b.tolist(),
            "R_am": None if mag.R_am is None else mag.R_am.tolist(),
            "field": mag.field if math.isfinite(mag.field) else None, "dip_deg": mag.dip_deg}
