"""A calibration file's triads, temperature models and low-range/high-range pair read back
for ``imucal apply`` (method.md §11, §12, M16, M18): the sections
:mod:`imucal.io.calibration_sections` writes, every number checked, so a damaged file is one
line naming the field."""

from __future__ import annotations

from typing import Any

import numpy as np

from imucal.errors import ImucalError
from imucal.models import SensorModel
from imucal.stages.apply import Calibration
from imucal.stages.apply_triads import TABLE_ACC, CombinedSpec, TriadCal, TriadsCalibration
from imucal.stages.combine import ClipLevels
from imucal.stages.temperature import BiasPolynomial

TABLE_REFERENCE = "the calibrated accelerometer"


def load_triads(path: str, reference: Calibration) -> TriadsCalibration | None:
    """:func:`triads_from_dict` of the calibration file at ``path`` (read by
    :func:`~imucal.io.calibration_file.load_calibration` already: ``reference``)."""
    from imucal.io.calibration_file import _read_json

    return triads_from_dict(_read_json(path), reference, str(path))


def _array(x: Any, shape: tuple[int, ...], what: str) -> np.ndarray:
    if _has_bool(x):
        raise ValueError(f"{what} must hold numbers, not true/false")
    try:
        a = np.array(x, dtype=float)
    except (TypeError, ValueError):
        a = np.full(shape, np.nan)
    if a.shape != shape or not np.all(np.isfinite(a)):
        raise ValueError(f"{what} must be {' x '.join(map(str, shape))} finite numbers")
    return a


def _has_bool(x: Any) -> bool:
    return any(_has_bool(v) for v in x) if isinstance(x, list) else isinstance(x, bool)


def _rotation(x: Any, what: str) -> np.ndarray:
    R = _array(x, (3, 3), what)
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise ValueError(f"{what} must be a rotation")
    return R


def _polynomial(d: Any, sensor: str) -> BiasPolynomial:
    """One sensor's M16 from its temperature entry (b0, reference, span, coefficients; the
    accelerometer's T, K and scale slope)."""
    b0 = _array(d["b0"], (3,), "b0")
    span = _array(d["span_degC"], (2,), "span_degC")
    if span[1] < span[0]:
        raise ValueError("span_degC must be [low, high]")
    coefs = np.array(d["coefficients"], dtype=float)
    if coefs.ndim != 2 or coefs.shape[1] != 3 or not 1 <= len(coefs) <= 4 \
            or not np.all(np.isfinite(coefs)) or _has_bool(d["coefficients"]):
        raise ValueError("coefficients must be 1 to 4 rows of 3 finite numbers")
    t0 = float(_array(d["reference_degC"], (), "reference_degC"))
    model = slope = None
    if sensor == "accelerometer" and "T" in d:
        K = _array(d["K"], (3,), "K")
        if np.any(K == 0):
            raise ValueError("a scale factor in K is zero")
        model = SensorModel(T=_array(d["T"], (3, 3), "T"), K=K, b=b0)
    if d.get("scale_slope_per_degC") is not None:
        slope = _array(d["scale_slope_per_degC"], (3,), "scale_slope_per_degC")
    return BiasPolynomial(sensor=sensor, b0=b0, t0=t0, span=(float(span[0]), float(span[1])),
                          order=len(coefs) - 1, coefs=coefs, cv_rms=np.full(4, np.nan),
                          blocks=0, model=model, scale_slope=slope)


def _temperature(section: Any, field: str) -> dict[str, BiasPolynomial]:
    out = {}
    for sensor in ("accelerometer", "gyroscope"):
        if isinstance(section, dict) and isinstance(section.get(sensor), dict):
            try:
                out[sensor] = _polynomial(section[sensor], sensor)
            except (KeyError, TypeError, ValueError) as e:
                what = f"missing {e}" if isinstance(e, KeyError) else str(e)
                raise ValueError(f"{field}.{sensor}: {what}") from None
    return out


def _name(text: str) -> str:
    """A stream's name from a description: ``acc a2 (columns ...)`` -> ``acc a2``."""
    return " ".join(text.split(" ")[:2])


def triads_from_dict(data: dict, reference: Calibration, source: str
                     ) -> TriadsCalibration | None:
    """The file's triads (the reference first, its models ``reference``), temperature models and
    combined pair; None for a file with neither triads nor temperature (applied as it always
    was). Raises :class:`ImucalError` naming the field."""
    section, temp = data.get("triads"), data.get("temperature")
    if section is None and temp is None:
        return None
    field = "temperature"
    try:
        t = _temperature(temp, "temperature")
        ref_name = TABLE_ACC  # a table's pair: its a (the file says "the calibrated ...")
        field = "triads"
        if isinstance(section, dict) and isinstance(section.get("reference"), str) \
                and section["reference"] != TABLE_REFERENCE:
            ref_name = _name(section["reference"])
        triads = [TriadCal(name=ref_name, gyro=None, calibration=reference, R=np.eye(3),
                           acc_temp=t.get("accelerometer"), gyro_temp=t.get("gyroscope"))]
        from imucal.io.calibration_file import calibration_from_dict

        entries = section.get("triads", []) if isinstance(section, dict) else []
        for i, e in enumerate(entries):
            field = f"triads.triads[{i}]"
            if "segments" not in e or e.get("rotation_to_reference") is None:
                continue  # not calibrated, or not turned to the reference: not applied
            try:
                own = calibration_from_dict({"format": data.get("format"),
                                             "format_version": data.get("format_version"),
                                             "units": e["units"], "segments": e["segments"]},
                                            source=source)
            except ImucalError as err:
                raise ImucalError(err.problem, source=source,
                                  field=f"{field}.{err.field}") from None
            tt = _temperature(e.get("temperature"), f"{field}.temperature")
            shift = e.get("times_moved_by_s")
            triads.append(TriadCal(
                name=str(e["accelerometer"]), gyro=e.get("gyroscope"), calibration=own,
                R=_rotation(e["rotation_to_reference"], "rotation_to_reference"),
                acc_temp=tt.get("accelerometer"), gyro_temp=tt.get("gyroscope"),
                time_shift=0.0 if shift is None else -float(_array(shift, (), "times_moved_by_s"))))
        combined = None
        c = section.get("combined") if isinstance(section, dict) else None
        if isinstance(c, dict) and c.get("combined"):
            field = "triads.combined"
            lim = c["low_range_limits_raw"]
            lo, hi = _array(lim["lo"], (3,), "lo"), _array(lim["hi"], (3,), "hi")
            band = _array(c["band"], (2,), "band")
            if not np.all(hi > lo) or not 0 <= band[0] < band[1] <= 1:
                raise ValueError("the limits must have hi > lo and the band 0 <= u_1 < u_2 <= 1")
            names = [tc.name for tc in triads]
            for key in ("low_range", "high_range"):
                if c[key] not in names and _name(c[key]) not in names:
                    raise ValueError(f"{key} {c[key]!r} names no triad of the file")
            noise = c.get("high_range_noise_mg")
            combined = CombinedSpec(low=_name(c["low_range"]), high=_name(c["high_range"]),
                                    levels=ClipLevels(lo=lo, hi=hi, how=str(lim.get("how", ""))),
                                    band=(float(band[0]), float(band[1])),
                                    high_noise_mg=None if noise is None else float(noise))
    except ImucalError:
        raise
    except (KeyError, TypeError, ValueError, IndexError, AttributeError) as e:
        what = f"missing {e}" if isinstance(e, KeyError) else str(e)
        raise ImucalError(f"malformed calibration: {what}", source=source, field=field) from None
    return TriadsCalibration(triads=tuple(triads), combined=combined)
