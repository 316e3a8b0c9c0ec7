"""calib.json's other triads (method.md §11) and its temperature models (§12, M16) read back
for the exports: each triad's own calibration and its rotation to the reference (M12), each
sensor's bias polynomial in temperature as :class:`~imucal.stages.temperature.BiasPolynomial`
(so that an export is checked against imucal's own ``calibrated``), and the instance number
each triad takes in a flight controller's parameters.

A file without the sections reads as ``None``: the exports are then as they always were.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from imucal.errors import ImucalError
from imucal.io.calibration_file import FORMAT, FORMAT_VERSION, calibration_from_dict
from imucal.models import SensorModel
from imucal.stages.apply import Calibration, SegmentModels
from imucal.stages.temperature import ORDERS, BiasPolynomial


@dataclass(frozen=True)
class TriadExport:
    """One other triad of calib.json's ``triads`` section, calibrated."""

    name: str  # "acc a2": the accelerometer stream
    gyro: str | None  # its IMU's gyroscope stream, if it has one
    calibration: Calibration  # its own segments and units (method.md §11: the whole method)
    R: np.ndarray | None  # u_ref = R u (M12); None: not estimated
    angle_deg: float | None
    std_deg: float | None  # the rotation's total standard error
    temperature: dict[str, BiasPolynomial]  # "accelerometer"/"gyroscope" -> M16
    entry: dict  # the calib.json entry as written, for the json and yaml exports
    slot: int = 0  # the autopilot instance (0 the reference): see :func:`instance_slots`


@dataclass(frozen=True)
class Extras:
    """What calib.json holds beside the calibrated pair: the reference's temperature models
    and the other triads (empty when the file has none)."""

    reference: str
    temperature: dict[str, BiasPolynomial]
    triads: tuple[TriadExport, ...] = ()
    notes: tuple[str, ...] = ()  # triads left out, how instances were numbered
    convention: str | None = None
    temperature_model: str | None = None
    slot: int = 0  # the reference's autopilot instance


def read_extras(data: dict, path: Path, cal: Calibration) -> Extras | None:
    """The ``triads`` and ``temperature`` sections of a calib.json (``data``), checked; None
    when it has neither."""
    tsec, triads = data.get("temperature"), data.get("triads")
    if tsec is None and triads is None:
        return None
    temperature = read_thermal(tsec, cal, path, "temperature") if tsec is not None else {}
    out: list[TriadExport] = []
    notes: list[str] = []
    reference = "the calibrated accelerometer"
    convention = None
    if triads is not None:
        if not isinstance(triads, dict) or not isinstance(triads.get("triads"), list):
            raise ImucalError("expected an object with a list 'triads'", source=str(path),
                              field="triads")
        reference = str(triads.get("reference") or reference)
        convention = triads.get("convention")
        for i, entry in enumerate(triads["triads"]):
            tri = _read_triad(entry, path, f"triads.triads[{i}]")
            if tri is None:
                notes.append(f"{entry.get('accelerometer', f'triad {i + 1}')}: not calibrated "
                             "(calib.json says why), not exported")
            else:
                out.append(tri)
    slots, said = instance_slots(reference, [t.name for t in out])
    notes += said
    return Extras(reference=reference, temperature=temperature,
                  triads=tuple(replace(t, slot=s) for t, s in zip(out, slots[1:])),
                  notes=tuple(notes), convention=convention,
                  temperature_model=tsec.get("model") if isinstance(tsec, dict) else None,
                  slot=slots[0])


def _read_triad(entry: object, path: Path, where: str) -> TriadExport | None:
    if not isinstance(entry, dict) or not isinstance(entry.get("accelerometer"), str):
        raise ImucalError("expected a triad's entry with its 'accelerometer' stream",
                          source=str(path), field=where)
    if "segments" not in entry:
        return None  # its own calibration failed: calib.json says so in 'said'
    try:
        cal = calibration_from_dict({"format": FORMAT, "format_version": FORMAT_VERSION,
                                     "units": entry.get("units"),
                                     "segments": entry["segments"]}, source=str(path))
    except ImucalError as e:
        raise ImucalError(e.problem, source=str(path), field=f"{where}.{e.field}") from None
    R = entry.get("rotation_to_reference")
    if R is not None:
        R = _array(R, (3, 3), path, f"{where}.rotation_to_reference")
        if not (np.allclose(R @ R.T, np.eye(3), atol=1e-6) and np.linalg.det(R) > 0):
            raise ImucalError("expected a rotation matrix", source=str(path),
                              field=f"{where}.rotation_to_reference")
    std = (entry.get("rotation_std_deg") or {}).get("total")
    angle = entry.get("rotation_angle_deg")
    temp = entry.get("temperature")
    return TriadExport(
        name=entry["accelerometer"], gyro=entry.get("gyroscope"), calibration=cal, R=R,
        angle_deg=float(angle) if isinstance(angle, (int, float)) else None,
        std_deg=float(std) if isinstance(std, (int, float)) else None,
        temperature=read_thermal(temp, cal, path, f"{where}.temperature") if temp else {},
        entry=entry)


def read_thermal(sec: object, cal: Calibration, path: Path, where: str
                 ) -> dict[str, BiasPolynomial]:
    """A ``temperature`` section's sensors as M16 (:class:`BiasPolynomial`), each with the
    model its bias belongs to: the accelerometer's T and K fitted beside it (M17), the
    gyroscope's those of the (single) segment, both with ``b = b0``."""
    if not isinstance(sec, dict):
        raise ImucalError("expected an object", source=str(path), field=where)
    out = {}
    seg: SegmentModels = cal.segments[0]  # a run with temperature is one segment (§12)
    for sensor in ("accelerometer", "gyroscope"):
        s = sec.get(sensor)
        if s is None:
            continue
        w = f"{where}.{sensor}"
        if not isinstance(s, dict):
            raise ImucalError("expected an object", source=str(path), field=w)
        b0 = _array(s.get("b0"), (3,), path, f"{w}.b0")
        order = s.get("order")
        if type(order) is not int or order not in ORDERS:
            raise ImucalError("expected an order 0-3", source=str(path), field=f"{w}.order")
        coefs = _array(s.get("coefficients"), (order + 1, 3), path, f"{w}.coefficients")
        t0 = _array(s.get("reference_degC"), (), path, f"{w}.reference_degC")
        span = _array(s.get("span_degC"), (2,), path, f"{w}.span_degC")
        if not span[0] <= t0 <= span[1]:
            raise ImucalError("expected reference_degC inside span_degC", source=str(path),
                              field=f"{w}.span_degC")
        slope = s.get("scale_slope_per_degC")
        slope = None if slope is None else _array(slope, (3,), path,
                                                  f"{w}.scale_slope_per_degC")
        if sensor == "accelerometer":
            T = _array(s.get("T", seg.acc.T.tolist()), (3, 3), path, f"{w}.T")
            K = _array(s.get("K", seg.acc.K.tolist()), (3,), path, f"{w}.K")
        else:
            if seg.gyro is None:
                raise ImucalError("a gyroscope's bias in temperature, and no gyroscope model",
                                  source=str(path), field=w)
            T, K = seg.gyro.T, seg.gyro.K
        cv = s.get("cv_rms_by_order") or [None] * len(ORDERS)
        out[sensor] = BiasPolynomial(
            sensor=sensor, b0=b0, t0=float(t0), span=(float(span[0]), float(span[1])),
            order=order, coefs=coefs,
            cv_rms=np.array([np.nan if v is None else float(v) for v in cv]),
            blocks=int(s.get("static_blocks") or 0), notes=tuple(s.get("notes") or ()),
            model=SensorModel(T=T, K=K, b=b0), scale_slope=slope)
    return out


def _array(value: object, shape: tuple[int, ...], path: Path, where: str) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        a = np.zeros(0)
    if a.shape != shape or not np.all(np.isfinite(a)):
        what = "a number" if shape == () else f"{'x'.join(map(str, shape))} finite numbers"
        raise ImucalError(f"expected {what}", source=str(path), field=where)
    return a


# A stream's instance as its source numbers it: a ULog multi-instance (sensor_accel:1, from
# 0), a DataFlash IMU message (IMU, IMU2, IMU3: from 1) or instance field (IMU[1]: from 0),
# a table's column prefix (a, a2, a3: from 1).
_NUMBERED = ((re.compile(r":(\d+)$"), 0), (re.compile(r"^IMU(\d*)$"), 1),
             (re.compile(r"^IMU\[(\d+)\]$"), 0), (re.compile(r"^a(\d*)$"), 1))


def stream_instance(name: str) -> int | None:
    """The 0-based instance a stream's name states (``acc sensor_accel:1 (…)`` -> 1, ``acc
    IMU2`` -> 1, ``acc a2`` -> 1), None where it states none."""
    token = name.split(" (")[0].split(" ", 1)[-1]
    for pattern, first in _NUMBERED:
        m = pattern.search(token)
        if m:
            return int(m.group(1) or first) - first
    return None


def instance_slots(reference: str, names: list[str]) -> tuple[list[int], list[str]]:
    """The autopilot instance of the reference and of each other triad: the one its stream
    states where every one states a different one (a log's IMU n is the autopilot's IMU n),
    else their order in calib.json (the reference 0), and said."""
    ref = 0 if reference == "the calibrated accelerometer" else stream_instance(reference)
    stated = [ref] + [stream_instance(n) for n in names]
    if None not in stated and len(set(stated)) == len(stated):
        return [int(s) for s in stated], []
    order = list(range(len(stated)))
    said = [] if not names else [
        "instances numbered in calib.json's order (the reference 0, then its triads): the "
        "streams' names do not each state one; check them against the autopilot's"]
    return order, said
