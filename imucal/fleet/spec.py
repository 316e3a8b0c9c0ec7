"""Pass/fail against a spec: limits a maker ships units within, read from a TOML file.

```toml
acc_bias_mg = 40            # |b| of every axis, milli-g (method.md M2's b)
acc_scale_pct = 3           # |s - 1| of every axis, percent (M2's K)
acc_misalignment_mrad = 10  # |a_yz|, |a_zy|, |a_zx| (M2's T), milliradians
gyro_bias_dps = 1           # |b_g| of every axis, deg/s (M4)
gyro_scale_pct = 3          # |s_g - 1|, percent (M4's K_g)
gyro_misalignment_mrad = 10 # the six angles of M4's T_g
static_norm_error_mg = 1    # static norm error after calibration (method.md §5)
gravity_error_deg = 0.5     # gravity prediction error after calibration (§5)
```

Every limit is optional. A limit the session cannot be judged on (a bias or scale in raw
counts, which has no nominal; a gyroscope figure of an accelerometer-only session) is listed
as unchecked, not passed.
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
        return {"after": row.get("static_norm_rms_mg_after")}
    if key == "gravity_error_deg":
        return None if gyro_raw is None else {"after": row.get("gravity_angle_rms_deg_after")}
    raise KeyError(key)


def _scaled(x: float | None, k: float) -> float | None:
    return None if x is None else x * k


def _minus1(x: float | None) -> float | None:
    return None if x is None else x - 1.0


def check(spec: Spec, row: dict[str, Any]) -> Verdict:
    """Judge one summary row (see :mod:`imucal.fleet.summary`) against the limits."""
    broken, unchecked = [], []
    for key, limit in spec.limits.items():
        values = _values(row, key)
        if values is None or any(v is None for v in values.values()):
            unchecked.append(key)
            continue
        unit = LIMITS[key]
        for name, v in values.items():
            if abs(v) >= limit:
                broken.append(f"{key}: {name} = {v:.4g} {unit} (limit {limit:g})")
    return Verdict(passed=not broken, broken=broken, unchecked=unchecked)
