"""What a column's name says it holds (method.md §0): a role (time, an axis of a sensor, a
sample counter) and, where the name carries one, a unit.

Names are compared with case and punctuation removed ("Acc_X" -> "accx"); a unit may follow in
brackets ("Acc X (m/s^2)") or as trailing tokens ("acc_x_ms2").
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from imucal.io.units import (
    ACC_UNIT_KEYS,
    GYRO_UNIT_KEYS,
    TIME_UNIT_KEYS,
    unit_key,
    unit_key_spaced,
)

ROLES = ("t", "ax", "ay", "az", "gx", "gy", "gz")
AXES = {"acc": ("ax", "ay", "az"), "gyro": ("gx", "gy", "gz")}
LABELS = {"acc": "accelerometer", "gyro": "gyroscope"}

_ACC_PREFIXES = ("a", "acc", "accl", "accel", "acceleration", "accelerometer", "linacc",
                 "linearacceleration")
_GYRO_PREFIXES = ("g", "w", "gyr", "gyro", "gyroscope", "omega", "angvel", "angularvelocity",
                  "angularrate")
_TIME_NAMES = ("t", "ts", "time", "times", "timestamp", "timestamps", "seconds", "sec",
               "elapsed", "elapsedtime", "timesec",
               "zeit", "tiempo", "temps", "tempo", "tid")  # de, es, fr, it/pt, sv/da/no
# Sample counters look like time (increasing numbers) but are not: never use them as time.
_COUNTER_NAMES = ("n", "nsample", "nsamples", "sample", "samples", "samplenumber", "samplenr",
                  "sampleindex", "sampleidx", "samplecounter", "index", "idx", "counter", "count",
                  "frame", "framenumber", "seq", "sequence", "packetcounter")


def _build_name_table() -> dict[str, str]:
    table: dict[str, str] = {}
    for sensor, prefixes in (("a", _ACC_PREFIXES), ("g", _GYRO_PREFIXES)):
        for prefix in prefixes:
            for axis in "xyz":
                table[prefix + axis] = sensor + axis
                if len(prefix) > 1:  # "x_acc" yes, "xa" no
                    table[axis + prefix] = sensor + axis
    table.update({name: "t" for name in _TIME_NAMES})
    table.update({name: "counter" for name in _COUNTER_NAMES})
    return table


_NAME_TABLE = _build_name_table()


@dataclass(frozen=True)
class ColumnMeaning:
    role: str | None  # one of ROLES, "counter", or None (not understood)
    unit: str | None = None  # canonical unit from the name, if it carried a valid one


def classify_name(name: str, single_sensor: str | None) -> ColumnMeaning:
    """Meaning of a column name; ``single_sensor`` lets a per-sensor file call axes x, y, z."""
    text = name.strip().strip("\"'").lower()
    bracket_unit = None
    match = re.search(r"[(\[{]([^)\]}]*)[)\]}]\s*$", text)  # "Acc X (m/s^2)", "time [ms]"
    if match:
        bracket_unit = unit_key(match.group(1))
        text = text[: match.start()]
    tokens = re.findall(r"[a-z0-9]+", unit_key_spaced(text))
    generic = {}  # plain x, y, z only mean something in a file holding one sensor
    if single_sensor is not None:
        generic = dict(zip("xyz", AXES[single_sensor], strict=True))
    # Try the whole name first, then peel 1-3 trailing tokens off as a unit ("acc_x_m_s2").
    for k in range(0, min(3, len(tokens) - 1) + 1):
        base = "".join(tokens[: len(tokens) - k])
        unit = "".join(tokens[len(tokens) - k :]) if k else bracket_unit
        role = _NAME_TABLE.get(base) or generic.get(base)
        if role is None:
            continue
        canonical = _unit_for_role(role, unit)
        if k == 0 or canonical is not None:
            return ColumnMeaning(role, canonical)
    return ColumnMeaning(None)


def _unit_for_role(role: str, unit: str | None) -> str | None:
    if unit is None:
        return None
    if role in AXES["acc"]:
        return ACC_UNIT_KEYS.get(unit)
    if role in AXES["gyro"]:
        return GYRO_UNIT_KEYS.get(unit)
    if role == "t":
        return TIME_UNIT_KEYS.get(unit)
    return None
