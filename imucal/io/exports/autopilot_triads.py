"""PX4 and ArduPilot parameter files of a calibration with several triads (method.md §11) or a
bias in temperature (§12): one instance per IMU and the thermal parameters
(:mod:`imucal.io.exports.thermal` states the targets' equations).

Each IMU's instance n is the one its stream states (a log's IMU n; the reference's own, a
table's ``a2`` is the second), else calib.json's order: PX4's ``CAL_ACCn_*``/``CAL_GYROn_*``
(n from 0; matched to the sensor by ``CAL_ACCn_ID``, a device id the user sets) and
``TC_An_*``/``TC_Gn_*``; ArduPilot's ``INS_ACCOFFS``/``INS_ACC2OFFS``/``INS_ACC3OFFS`` (and
``SCAL``), ``INS_GYROFFS``/``INS_GYR2OFFS``/``INS_GYR3OFFS`` and ``INS_TCALn_*`` (n from 1).
Each instance is corrected in its own sensor frame (as :mod:`imucal.io.exports.autopilot`):
diagonal scale, no misalignment, and neither target has a parameter for a triad's rotation
to the reference (M12): what each drops is said per instance, in mg and % of the rate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from imucal.errors import ImucalError
from imucal.io.exports import thermal
from imucal.io.exports.common import (
    Exported,
    ExportInput,
    fmt_num,
    require_gyro_rad,
    segment_list,
    si_acc_factors,
)
from imucal.io.exports.diagonal import diagonal_acc, dropped_gyro_percent, dropped_misalignment_mg
from imucal.io.exports.mag import ardupilot_mag, px4_mag
from imucal.models import SensorModel
from imucal.stages.apply import Calibration, SegmentModels
from imucal.stages.temperature import BiasPolynomial

PX4_MAX = 4  # CAL_ACC0..3, TC_A0..3 (calibration::Accelerometer::MAX_SENSOR_COUNT)
ARDUPILOT_MAX = 3  # INS_ACCOFFS, INS_ACC2OFFS, INS_ACC3OFFS; INS_TCAL1..3


@dataclass(frozen=True)
class Instance:
    """One IMU as an autopilot's instance: its models (the temperature model's accelerometer
    where it has one), in SI units."""

    slot: int
    label: str
    acc: SensorModel
    gyro: SensorModel | None
    temperature: dict[str, BiasPolynomial]
    c_in: float  # m/s^2 per raw accelerometer unit
    c_out: float  # m/s^2 per calibrated unit
    g: float  # |g| in the calibrated unit
    notes: tuple[str, ...]

    @property
    def offset_scale(self) -> tuple[np.ndarray, np.ndarray]:
        return diagonal_acc(self.acc, self.c_in, self.c_out)


def instances(inp: ExportInput, segment: int | None, fmt: str) -> tuple[list[Instance], list[str]]:
    """The reference and each other triad as instances, with what each loses; and the notes
    for the whole file."""
    ext = inp.extras
    assert ext is not None
    index, seg = inp.segment(segment, fmt)
    target = {"px4": "PX4", "ardupilot": "ArduPilot"}[fmt]
    out = [_instance(inp, fmt, ext.slot, f"{ext.reference} (the reference)", inp.calibration,
                     seg, ext.temperature, None, target)]
    for tri in ext.triads:
        tseg = _triad_segment(inp, tri.name, tri.calibration, seg, segment)
        out.append(_instance(inp, fmt, tri.slot, tri.name, tri.calibration, tseg,
                             tri.temperature, tri, target))
    n = len(inp.calibration.segments)
    notes = list(ext.notes) + ([f"segment {index} of {n} only"] if n > 1 else [])
    return out, notes


def _triad_segment(inp: ExportInput, name: str, cal: Calibration, ref: SegmentModels,
                   segment: int | None) -> SegmentModels:
    """A triad's one segment: its only one, or with ``--segment`` the one that overlaps the
    reference's chosen segment longest."""
    segs = cal.segments
    if len(segs) == 1:
        return segs[0]
    if segment is None:
        raise ImucalError(f"{name} has {len(segs)} segments ({segment_list(segs)}) and the "
                          "format holds one model per sensor; choose the reference's segment "
                          "with --segment N (the triad's overlapping it longest is taken)",
                          source=str(inp.path), field="triads")
    overlap = [min(s.t_end, ref.t_end) - max(s.t_start, ref.t_start) for s in segs]
    return segs[int(np.argmax(overlap))]


def _instance(inp: ExportInput, fmt: str, slot: int, label: str, cal: Calibration,
              seg: SegmentModels, temperature: dict[str, BiasPolynomial], tri, target: str
              ) -> Instance:
    c_in, c_out = si_acc_factors(inp, fmt, cal)
    require_gyro_rad(inp, fmt, cal)
    acc_fit = temperature.get("accelerometer")
    acc = acc_fit.model if acc_fit is not None else seg.acc
    notes = []
    rms, mx = dropped_misalignment_mg(acc, cal.g)
    notes.append(f"accelerometer: diagonal scale only; dropping the misalignment leaves {rms:.3g} "
                 f"mg RMS, {mx:.3g} mg at most, on a still device (computed from the model over "
                 "2000 directions on the sphere)")
    if seg.gyro is not None:
        grms, gmx = dropped_gyro_percent(seg.gyro)
        notes.append(f"gyroscope: offsets only; dropping its scale and misalignment leaves "
                     f"{grms:.3g} % of the rate RMS, {gmx:.3g} % at most (over directions)")
    if acc_fit is not None:
        notes += thermal.slope_note(acc_fit, cal.g, target)
    for fit in temperature.values():
        notes.append(f"{fit.sensor}: bias of order {fit.order} in temperature, "
                     f"{fit.span[0]:.1f}-{fit.span[1]:.1f} deg C (held at its ends outside), "
                     "exact")
    if tri is not None:
        if tri.R is None:
            notes.append(f"its rotation to the reference was not estimated (calib.json says "
                         f"why); {target} has no parameter for one either")
        else:
            theta = math.radians(tri.angle_deg if tri.angle_deg is not None
                                 else _angle_deg(tri.R))
            chord = 2.0 * math.sin(theta / 2.0)  # |R u - u| at most, for a unit vector u
            std = f" (+- {tri.std_deg:.2g})" if tri.std_deg is not None else ""
            notes.append(f"its rotation to the reference, {math.degrees(theta):.3g} deg{std}, "
                         f"is not held ({target} has no parameter for it): its vectors stay "
                         f"in its own frame, up to {chord * 1000:.3g} mg from the reference's "
                         "on a still device" + (f", {chord * 100:.3g} % of the rate for its "
                                                "gyroscope" if seg.gyro is not None else ""))
    gyro = seg.gyro
    gyro_fit = temperature.get("gyroscope")
    if gyro is not None and gyro_fit is not None:
        gyro = gyro_fit.model
    return Instance(slot=slot, label=label, acc=acc, gyro=gyro, temperature=temperature,
                    c_in=c_in, c_out=c_out, g=cal.g, notes=tuple(notes))


def _angle_deg(R: np.ndarray) -> float:
    return math.degrees(math.acos(float(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def _kept(units: list[Instance], limit: int, target: str) -> tuple[list[Instance], list[str]]:
    kept = [u for u in units if u.slot < limit]
    said = [f"{u.label}: instance {u.slot} is beyond the {limit} {target} holds; not written"
            for u in units if u.slot >= limit]
    return kept, said


def _comments(units: list[Instance], name: str) -> list[str]:
    lines = []
    for u in units:
        lines.append(f"{name(u)}: {u.label}")
        lines += [f"  {n}" for n in u.notes]
    return lines


def px4(inp: ExportInput, out: Path, segment: int | None) -> Exported:
    """PX4 (QGroundControl .params): one ``CAL_ACCn``/``CAL_GYROn`` set per IMU, ``TC_An``/
    ``TC_Gn`` for a bias in temperature."""
    units, notes = instances(inp, segment, "px4")
    units, said = _kept(units, PX4_MAX, "PX4")
    notes += said
    mag = px4_mag(inp.magnetometer) if inp.magnetometer is not None else None
    rows: list[tuple[str, float, int]] = []
    for u in units:
        off, scale = u.offset_scale
        n = u.slot
        rows += [(f"CAL_ACC{n}_{a}OFF", o, 9) for a, o in zip("XYZ", off)]
        rows += [(f"CAL_ACC{n}_{a}SCALE", s, 9) for a, s in zip("XYZ", scale)]
        if u.gyro is not None:
            rows += [(f"CAL_GYRO{n}_{a}OFF", o, 9) for a, o in zip("XYZ", u.gyro.b)]
    for kind, sensor in (("A", "accelerometer"), ("G", "gyroscope")):
        with_t = [u for u in units if sensor in u.temperature]
        if with_t:
            rows.append((f"TC_{kind}_ENABLE", 1, 6))  # INT32
            # PX4's thermal calibration guide: with TC_x_ENABLE = 1 its own later calibration
            # moves the X0 coefficients (and resets CAL_*OFF/SCALE) instead.
            notes.append(f"TC_{kind}_ENABLE = 1: a later {sensor} calibration in PX4 adjusts "
                         f"TC_{kind}n_X0 instead of the CAL parameters")
        for u in with_t:
            per = u.c_in if sensor == "accelerometer" else 1.0
            rows += [(name, v, 9) for name, v in thermal.px4_rows(kind, u.slot,
                                                                   u.temperature[sensor], per)]
    head = ["PX4 parameters: a = (a_m - thermal(T) - CAL_ACCn_xOFF) * CAL_ACCn_xSCALE (m/s^2, "
            "sensor frame); w = w_m - thermal(T) - CAL_GYROn_xOFF (rad/s); thermal(T) = X0 + X1 "
            "dT + X2 dT^2 + X3 dT^3, dT = clip(T, TMIN, TMAX) - TREF (TC_An_*, TC_Gn_*), zero "
            "without them", *inp.header_lines(),
            *_comments(units, lambda u: f"instance {u.slot}"), *notes,
            *(mag.notes + mag.comments if mag is not None else []),
            "set CAL_ACCn_ID / CAL_GYROn_ID (and TC_An_ID / TC_Gn_ID) to your sensors' device "
            "ids", "Vehicle-Id Component-Id Name Value Type"]
    lines = [f"# {h}" for h in head]
    lines += [f"1\t1\t{name}\t{int(v)}\t6" if t == 6 else f"1\t1\t{name}\t{fmt_num(v)}\t9"
              for name, v, t in rows]
    if mag is not None:  # CAL_MAG0_ROT is an INT32 parameter (type 6)
        lines += [f"1\t1\t{name}\t{int(v)}\t6" if name.endswith("_ROT") else
                  f"1\t1\t{name}\t{fmt_num(v)}\t9" for name, v in mag.rows]
    return Exported(files=[(out, "\n".join(lines) + "\n")],
                    notes=_flat(units) + notes + (mag.notes if mag is not None else []))


def _ap(kind: str, k: int) -> str:
    """ArduPilot's name of instance k (from 1): INS_ACCOFFS, INS_ACC2OFFS, INS_GYR2OFFS..."""
    base = {"ACCOFFS": ("ACC", "OFFS"), "ACCSCAL": ("ACC", "SCAL"), "GYROFFS": ("GYR", "OFFS")}
    a, b = base[kind]
    return f"INS_{kind}" if k == 1 else f"INS_{a}{k}{b}"


def ardupilot(inp: ExportInput, out: Path, segment: int | None) -> Exported:
    """ArduPilot (.param): ``INS_ACC[n]OFFS``/``SCAL`` and ``INS_GYR[n]OFFS`` per IMU,
    ``INS_TCALn_*`` and the calibration temperatures for a bias in temperature."""
    units, notes = instances(inp, segment, "ardupilot")
    units, said = _kept(units, ARDUPILOT_MAX, "ArduPilot")
    notes += said
    mag = ardupilot_mag(inp.magnetometer) if inp.magnetometer is not None else None
    rows: list[tuple[str, float]] = []
    ints = {"COMPASS_ORIENT"}
    for u in units:
        k = u.slot + 1
        off, scale = u.offset_scale
        goff = None if u.gyro is None else u.gyro.b
        tc = thermal.ardupilot(k, u.temperature, {"accelerometer": u.c_in, "gyroscope": 1.0})
        off = tc.offsets.get("accelerometer", off)
        goff = tc.offsets.get("gyroscope", goff) if goff is not None else None
        if np.any(np.abs(off) > 3.5) or np.any(np.abs(scale - 1.0) > 0.2):
            notes.append(f"IMU {k}: outside ArduPilot's accepted range (|offset| <= 3.5 "
                         "m/s^2, scale 0.8..1.2): it will refuse these values")
        notes += tc.notes
        rows += [(f"{_ap('ACCOFFS', k)}_{a}", o) for a, o in zip("XYZ", off)]
        rows += [(f"{_ap('ACCSCAL', k)}_{a}", s) for a, s in zip("XYZ", scale)]
        if goff is not None:
            rows += [(f"{_ap('GYROFFS', k)}_{a}", o) for a, o in zip("XYZ", goff)]
        rows += tc.rows
        ints.add(f"INS_TCAL{k}_ENABLE")
    head = ["ArduPilot parameters: accel -= thermal(T); accel -= INS_ACC[n]OFFS; accel *= "
            "INS_ACC[n]SCAL (m/s^2, after the sensor's orientation); gyro -= thermal(T); gyro "
            "-= INS_GYR[n]OFFS (rad/s); thermal(T) = P(clip(T) - 35) - P(clip(INS_ACCn_CALTEMP) "
            "- 35), P(x) = (ACC1 + (ACC2 + ACC3 x) x) x * 1e-6 (INS_TCALn_*, clipped to its "
            "TMIN..TMAX), zero without them", *inp.header_lines(),
            *_comments(units, lambda u: f"IMU {u.slot + 1}"), *notes,
            *(mag.notes + mag.comments if mag is not None else [])]
    lines = [f"# {h}" for h in head]
    if mag is not None:
        rows += mag.rows
    lines += [f"{name},{int(v)}" if name in ints else f"{name},{fmt_num(v)}"
              for name, v in rows]
    return Exported(files=[(out, "\n".join(lines) + "\n")],
                    notes=_flat(units) + notes + (mag.notes if mag is not None else []))


def _flat(units: list[Instance]) -> list[str]:
    return [f"instance {u.slot} ({u.label}): {n}" for u in units for n in u.notes]
