"""What a column's name says it holds (method.md §0): a role (time, an axis of a sensor, a
sample counter) and, where the name carries one, a unit.

Names are compared with case and punctuation removed ("Acc_X" -> "accx"); a unit may follow in
brackets ("Acc X (m/s^2)") or as trailing tokens ("acc_x_ms2").
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from imucal.io.units import (
    ACC_NAME_UNITS,
    GYRO_NAME_UNITS,
    TIME_UNIT_KEYS,
    unit_key,
    unit_key_spaced,
)

ROLES = ("t", "ax", "ay", "az", "gx", "gy", "gz")
AXES = {"acc": ("ax", "ay", "az"), "gyro": ("gx", "gy", "gz")}
LABELS = {"acc": "accelerometer", "gyro": "gyroscope"}
# The streams a table may hold beside the calibrated pair, by the same naming rule: a second
# and third accelerometer (a2x…, a3x…) and gyroscope (g2x…, g3x…), a magnetometer (mx, my, mz)
# and a temperature in deg C (temp). (kind, instance) -> its columns' roles.
EXTRA_AXES = {("acc", "a2"): ("a2x", "a2y", "a2z"), ("acc", "a3"): ("a3x", "a3y", "a3z"),
              ("gyro", "g2"): ("g2x", "g2y", "g2z"), ("gyro", "g3"): ("g3x", "g3y", "g3z"),
              ("mag", "m"): ("mx", "my", "mz"), ("temp", "temp"): ("temp",)}
EXTRA_ROLES = tuple(r for roles in EXTRA_AXES.values() for r in roles)
LABELS.update({"a2": "second accelerometer", "a3": "third accelerometer",
               "g2": "second gyroscope", "g3": "third gyroscope", "m": "magnetometer",
               "temp": "temperature"})
# Units a magnetometer's or a thermometer's column name may carry.
EXTRA_NAME_UNITS = {"mag": {"ut": "uT", "microtesla": "uT", "gauss": "gauss", "ga": "gauss",
                            "mg": "mG", "mgauss": "mG", "milligauss": "mG", "t": "T",
                            "tesla": "T", "counts": "counts", "raw": "counts", "lsb": "counts"},
                    "temp": {"c": "degC", "degc": "degC", "celsius": "degC"}}
ALL_ROLES = ROLES + EXTRA_ROLES

# Prefixes of an axis letter, as real loggers write them: "acc_x", "Acc_X" (Xsens MT Manager),
# "AcX"/"GyX" (Arduino MPU-6050 sketches), "Acceleration x" / "Gyroscope x" (Phyphox, x-io),
# "linear_acceleration.x" / "angular_velocity.x" (ROS sensor_msgs/Imu), "gFx" (g-force in g,
# Physics Toolbox), "rotationRate.x" (iOS), "A_X"/"G_X" (ST), "accelerationIncludingGravity.x".
_ACC_PREFIXES = ("a", "ac", "acc", "accl", "accel", "acceleration", "accelerometer",
                 "accelerationincludinggravity", "gf")
_GYRO_PREFIXES = ("g", "w", "gy", "gyr", "gyro", "gyroscope", "omega", "angvel", "angularvel",
                  "angularvelocity", "angularrate", "rotationrate", "rotrate")
# Worse matches, taken only where nothing better names the axis: on Android "linear
# acceleration" has gravity removed, and sits beside the accelerometer ("ROS linear_acceleration"
# is the accelerometer itself, and alone there).
_ACC_PREFIXES_WORSE = ("linacc", "linearacceleration")
_IMPLIED_UNITS = {"gf": "g"}  # a prefix that says the unit
_TIME_NAMES = ("t", "ts", "time", "times", "timestamp", "timestamps", "seconds", "sec",
               "elapsed", "elapsedtime", "timesec", "unixtime", "epoch", "utc",
               "zeit", "tiempo", "temps", "tempo", "tid")  # de, es, fr, it/pt, sv/da/no
# Time of the sample itself, chosen over a plain "time" (often when a row was logged): ROS's
# header stamp beside rosbag's %time, Sensor Logger's seconds_elapsed beside its epoch time.
_SAMPLE_TIME_NAMES = {"stamp": None, "headerstamp": None, "secondselapsed": "s",
                      "elapsedseconds": "s", "timeelapsed": None, "timesincestart": None,
                      "sampletime": None, "sampletimefine": "100us",  # Xsens: 10 kHz ticks
                      "millis": "ms", "micros": "us"}  # Arduino's millis() and micros()
_MAG_PREFIXES = ("m", "mag", "magn", "magnetometer", "magneticfield", "compass")
_TEMP_NAMES = ("temp", "temperature", "tempc", "temperaturec", "tempdegc", "temperaturedegc",
               "imutemp", "imutemperature")
# Sample counters look like time (increasing numbers) but are not: never use them as time.
_COUNTER_NAMES = ("n", "nsample", "nsamples", "sample", "samples", "samplenumber", "samplenr",
                  "sampleindex", "sampleidx", "samplecounter", "sampleid", "index", "idx",
                  "counter", "count", "frame", "framenumber", "seq", "sequence", "packetcounter",
                  "packetcount", "packetnumber", "packetindex")
# Words that change what follows: "free_acc_x" or "gravity_x" is no raw accelerometer, so
# they are never dropped from the front of a name to find a role in the rest.
_MODIFIERS = {"free", "user", "linear", "lin", "gravity", "grav", "mag", "magnetic",
              "magnetometer", "orientation", "euler", "quat", "quaternion", "delta", "d",
              "filtered", "global", "world", "earth", "nav", "velocity", "vel", "position",
              "pos", "temp", "temperature"}


@dataclass(frozen=True)
class _Entry:
    role: str
    rank: int = 0  # of two columns with one role, the lower rank is taken
    unit: str | None = None  # a unit the name itself implies


def _build_name_table() -> dict[str, _Entry]:
    table: dict[str, _Entry] = {}
    for sensor, prefixes, rank in (("a", _ACC_PREFIXES, 0), ("g", _GYRO_PREFIXES, 0),
                                   ("a", _ACC_PREFIXES_WORSE, 1)):
        for prefix in prefixes:
            entry = {axis: _Entry(sensor + axis, rank, _IMPLIED_UNITS.get(prefix))
                     for axis in "xyz"}
            for axis in "xyz":
                table.setdefault(prefix + axis, entry[axis])
                if len(prefix) > 1:  # "x_acc" yes, "xa" no
                    table.setdefault(axis + prefix, entry[axis])
    for n in "23":  # "a2x", "acc2_x", "accel2x"; "g2x", "gyro2_x"
        for sensor, prefixes in (("a", ("a", "acc", "accel")), ("g", ("g", "gyr", "gyro"))):
            for prefix in prefixes:
                for axis in "xyz":
                    table.setdefault(f"{prefix}{n}{axis}", _Entry(f"{sensor}{n}{axis}"))
    for prefix in _MAG_PREFIXES:
        for axis in "xyz":
            table.setdefault(prefix + axis, _Entry("m" + axis))
    table.update({name: _Entry("temp") for name in _TEMP_NAMES})
    table.update({name: _Entry("t", 1) for name in _TIME_NAMES})
    table.update({name: _Entry("t", 0, unit) for name, unit in _SAMPLE_TIME_NAMES.items()})
    table.update({name: _Entry("counter") for name in _COUNTER_NAMES})
    return table


_NAME_TABLE = _build_name_table()


@dataclass(frozen=True)
class ColumnMeaning:
    role: str | None  # one of ROLES, "counter", or None (not understood)
    unit: str | None = None  # canonical unit from the name, if it carried a valid one
    rank: int = 0  # of two columns with one role, the lower rank is taken


def classify_name(name: str, single_sensor: str | None) -> ColumnMeaning:
    """Meaning of a column name; ``single_sensor`` lets a per-sensor file call axes x, y, z.

    A name may carry words in front of the role ("field.linear_acceleration.x" of a rosbag
    export, "/imu/angular_velocity/x" of PlotJuggler, "BMI160 acc x"): up to three are tried
    off, but never a word that changes the meaning ("free_acc_x")."""
    text = name.strip().strip("\"'").lower()
    bracket_unit = None
    match = re.search(r"[(\[{]([^)\]}]*)[)\]}]\s*$", text)  # "Acc X (m/s^2)", "time [ms]"
    if match:
        bracket_unit = unit_key(match.group(1))
        text = text[: match.start()]
    tokens = re.findall(r"[a-z0-9]+", unit_key_spaced(text))
    generic = {}  # plain x, y, z only mean something in a file holding one sensor
    if single_sensor is not None:
        generic = {axis: _Entry(role) for axis, role in zip("xyz", AXES[single_sensor],
                                                            strict=True)}
    for drop in range(0, min(3, len(tokens) - 1) + 1):
        if drop and tokens[drop - 1] in _MODIFIERS:
            break
        meaning = _match(tokens[drop:], bracket_unit, generic)
        if meaning is not None:
            return meaning
    return ColumnMeaning(None)


def _match(tokens: list[str], bracket_unit: str | None,
           generic: dict[str, _Entry]) -> ColumnMeaning | None:
    # Try the whole name first, then peel 1-3 trailing tokens off as a unit ("acc_x_m_s2"),
    # with an "in" before them ("Time since start in ms").
    for k in range(0, min(3, len(tokens) - 1) + 1):
        head = tokens[: len(tokens) - k]
        if k and len(head) > 1 and head[-1] == "in":
            head = head[:-1]
        entry = _NAME_TABLE.get("".join(head)) or generic.get("".join(head))
        if entry is None:
            continue
        unit = "".join(tokens[len(tokens) - k :]) if k else bracket_unit
        canonical = _unit_for_role(entry.role, unit)
        if k == 0 or canonical is not None:
            return ColumnMeaning(entry.role, canonical or entry.unit, entry.rank)
    return None


def _unit_for_role(role: str, unit: str | None) -> str | None:
    if unit is None:
        return None
    if role in AXES["acc"]:
        return ACC_NAME_UNITS.get(unit)
    if role in AXES["gyro"]:
        return GYRO_NAME_UNITS.get(unit)
    if role == "t":
        return TIME_UNIT_KEYS.get(unit)
    if role in ("mx", "my", "mz"):
        return EXTRA_NAME_UNITS["mag"].get(unit)
    if role == "temp":
        return EXTRA_NAME_UNITS["temp"].get(unit)
    return None
