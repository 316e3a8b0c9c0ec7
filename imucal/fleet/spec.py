"""Pass/fail against a spec: limits a maker ships units within, read from a TOML file.

```toml
acc_bias_mg = 40            # |b| of every axis, milli-g (method.md M2's b)
acc_scale_pct = 3           # |s - 1| of every axis, percent (M2's K)
acc_misalignment_mrad = 10  # |a_yz|, |a_zy|, |a_zx| (M2's T), milliradians
gyro_bias_dps = 1           # |b_g| of every axis, deg/s (M4)
gyro_scale_pct = 3          # |s_g - 1|, percent (M4's K_g)
gyro_misalignment_mrad = 10 # the six angles of M4's T_g
static_norm_error_mg = 1    # static norm error held out of the fit (method.md §5)
gravity_error_deg = 0.5     # gravity prediction error held out of the fit (§5)
```

Every limit is optional. The error figures judged are the held-out ones (each still pose, each
turn, predicted by a fit that did not see it): the in-sample ones flatter a fit with few poses
(a six-pose session: 0.226 mg in-sample, 16.9 mg held out). What the data do not determine
cannot be within a limit (issue 27): a parameter with no standard error (the data alone leave
it undetermined, :mod:`imucal.numerics.determinacy`) breaks its own limit, and the figure
limits of its sensor too, since no held-out pose or turn measured the direction it governs.
A limit the session cannot be judged on (a bias or scale in raw counts, which has no nominal;
a gyroscope figure of an accelerometer-only session; a held-out figure not computed) is
listed as unchecked, and fails the spec: a spec passes only what it judged.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from imucal.errors import ImucalError
from imucal.models import ACC_PARAM_NAMES, GYRO_PARAM_NAMES
from imucal.session import STANDARD_GRAVITY

LIMITS: dict[str, str] = {
    "acc_bias_mg": "mg", "acc_scale_pct": "%", "acc_misalignment_mrad": "mrad",
    "gyro_bias_dps": "deg/s", "gyro_scale_pct": "%", "gyro_misalignment_mrad": "mrad",
    "static_norm_error_mg": "mg", "gravity_error_deg": "deg",
}


@dataclass(frozen=True)
class Spec:
    limits: dict[str, float]
    source: str = "<memory>"

    @property
    def hash(self) -> str:
        text = json.dumps(self.limits, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass(frozen=True)
class Verdict:
    passed: bool
    broken: list[str] = field(default_factory=list)
    unchecked: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {"pass": self.passed, "broken": self.broken, "unchecked": self.unchecked}


def _toml():
    try:
        import tomllib  # Python 3.11+
    except ModuleNotFoundError:  # pragma: no cover - Python 3.10
        try:
            import tomli as tomllib
        except ModuleNotFoundError:
            raise ImucalError("reading a spec needs Python 3.11 or the 'tomli' package "
                              "(pip install tomli)", source="--spec") from None
    return tomllib


def load_spec(path: str | Path) -> Spec:
    """Read and check a limits file: known keys, positive finite numbers."""
    name = str(path)
    tomllib = _toml()
    try:
        data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ImucalError("file not found", source=name) from None
    except (OSError, UnicodeDecodeError) as e:
        raise ImucalError(f"cannot read the spec ({e.__class__.__name__})", source=name) from None
    except tomllib.TOMLDecodeError as e:
        raise ImucalError(f"not valid TOML ({e})", source=name) from None
    limits = {}
    for key, value in data.items():
        if key not in LIMITS:
            raise ImucalError(f"unknown limit; expected one of {', '.join(LIMITS)}",
                              source=name, field=key)
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        if not ok or not math.isfinite(value) or value <= 0:
            raise ImucalError(f"expected a positive number, got {value!r}", source=name,
                              field=key)
        limits[key] = float(value)
    if not limits:
        raise ImucalError(f"no limits; expected some of {', '.join(LIMITS)}", source=name)
    return Spec(limits=limits, source=name)


def _undetermined(row: dict[str, Any], sensor: str) -> list[str]:
    """The parameters of ``sensor`` ("acc", "gyro") fitted with no standard error: the data
    alone do not determine them (a calib.json's ``std`` null, a summary row's None)."""
    names = ACC_PARAM_NAMES if sensor == "acc" else GYRO_PARAM_NAMES
    return [n for n in names if row.get(f"{sensor}_{n}") is not None
            and _finite(row.get(f"{sensor}_std_{n}")) is None]


def _finite(x: Any) -> float | None:
    return None if x is None or not math.isfinite(float(x)) else float(x)


# The parameters each limit covers, and the sensor whose parameters a figure limit rests on.
_PARAMS = {"acc_bias_mg": ("acc", ACC_PARAM_NAMES[6:]),
           "acc_scale_pct": ("acc", ACC_PARAM_NAMES[3:6]),
           "acc_misalignment_mrad": ("acc", ACC_PARAM_NAMES[:3]),
           "gyro_scale_pct": ("gyro", GYRO_PARAM_NAMES[6:9]),
           "gyro_misalignment_mrad": ("gyro", GYRO_PARAM_NAMES[:6])}
_FIGURES = {"static_norm_error_mg": "acc", "gravity_error_deg": "gyro"}


def _not_determined(row: dict[str, Any], key: str) -> str | None:
    """Why ``key`` cannot pass on what the data leave undetermined; None when nothing is."""
    if key in _PARAMS:
        sensor, names = _PARAMS[key]
        weak = [n for n in _undetermined(row, sensor) if n in names]
        return None if not weak else (f"{key}: {', '.join(weak)} undetermined (the data do "
                                      "not measure them)")
    if key in _FIGURES:
        weak = _undetermined(row, _FIGURES[key])
        return None if not weak else (f"{key}: cannot be judged: {', '.join(weak)} "
                                      "undetermined (no held-out pose or turn measured the "
                                      "directions they govern)")
    return None


def _values(row: dict[str, Any], key: str) -> dict[str, float | None] | None:
    """The figures ``key`` limits, in its unit, by name; None when they cannot be judged."""
    acc_raw, gyro_raw = row.get("acc_unit_raw"), row.get("gyro_unit_raw")
    axes = ("x", "y", "z")
    if key == "acc_bias_mg":
        per_g = {"g": 1.0, "m/s^2": STANDARD_GRAVITY}.get(acc_raw)
        if per_g is None:
            return None
        return {f"b_{a}": _scaled(row[f"acc_b_{a}"], 1e3 / per_g) for a in axes}
    if key in ("acc_scale_pct", "gyro_scale_pct"):
        sensor = key.split("_")[0]
        if (acc_raw if sensor == "acc" else gyro_raw) not in ("g", "m/s^2", "rad/s"):
            return None
        return {f"s_{a}": _scaled(_minus1(row[f"{sensor}_s_{a}"]), 100.0) for a in axes}
    if key == "acc_misalignment_mrad":
        return {n: _scaled(row[f"acc_{n}"], 1e3) for n in ACC_PARAM_NAMES[:3]}
    if key == "gyro_misalignment_mrad":
        return None if gyro_raw is None else {
            n: _scaled(row[f"gyro_{n}"], 1e3) for n in GYRO_PARAM_NAMES[:6]}
    if key == "gyro_bias_dps":
        return None if gyro_raw != "rad/s" else {
            f"b_{a}": _scaled(row[f"gyro_b_{a}"], 180.0 / math.pi) for a in axes}
    if key == "static_norm_error_mg":
        return {"held out": _finite(row.get("static_norm_rms_mg_cv"))}
    if key == "gravity_error_deg":
        return None if gyro_raw is None else {
            "held out": _finite(row.get("gravity_angle_rms_deg_cv"))}
    raise KeyError(key)


def _scaled(x: float | None, k: float) -> float | None:
    return None if x is None else x * k


def _minus1(x: float | None) -> float | None:
    return None if x is None else x - 1.0


def check(spec: Spec, row: dict[str, Any]) -> Verdict:
    """Judge one summary row (see :mod:`imucal.fleet.summary`) against the limits: it passes
    when every limit was judged and none broken (see the module)."""
    broken, unchecked = [], []
    for key, limit in spec.limits.items():
        values = _values(row, key)
        if values is None:
            unchecked.append(key)
            continue
        open_ = _not_determined(row, key)
        if open_ is not None:
            broken.append(open_)
        unit = LIMITS[key]
        for name, v in values.items():
            if v is None:
                if open_ is None and key not in unchecked:
                    unchecked.append(key)
                continue
            if abs(v) >= limit:
                broken.append(f"{key}: {name} = {v:.4g} {unit} (limit {limit:g})")
    return Verdict(passed=not broken and not unchecked, broken=broken, unchecked=unchecked)
