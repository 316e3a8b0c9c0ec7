"""What a file says of its own recording in its preamble (method.md §0): the sample rate, the
unit of its time column, the length of its initial still period.

Keys are matched by their words, with case and punctuation removed ("Sample rate (Hz)",
``sample_rate_hz``, ``fs``, ``ODR``); a unit may stand in the key or after the value ("200 Hz",
"5 ms"). A key that names a sensor other than the accelerometer or the gyroscope is not read.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

from imucal.io.units import TIME_UNIT_KEYS, TIME_UNITS, unit_key_spaced

MAX_RATE_HZ = 100_000.0

_RATE_WORDS = {"rate", "samplerate", "samplingrate", "fs", "frequency", "freq", "hz", "odr",
               "sps", "datarate", "updaterate", "outputdatarate", "samplingfrequency"}
_PERIOD_WORDS = {"period", "interval", "dt", "sampleperiod", "samplinginterval",
                 "sampleinterval", "samplingperiod"}
_STILL_WORDS = {"still", "rest", "static", "stationary", "warmup"}
_INIT_WORDS = {"init", "initial"}  # a still period only where no rate word says otherwise
# Keys about another sensor, or about a rate that is no sample rate of the IMU.
_OTHER_SENSORS = {"mag", "magnetometer", "baro", "barometer", "pressure", "temp", "temperature",
                  "gps", "gnss", "audio", "mic", "display", "screen", "ecg", "ppg", "light",
                  "baud", "bitrate", "bps", "heart", "frame", "video", "camera"}
_SENSOR_WORDS = {"acc": {"a", "acc", "accel", "accl", "accelerometer", "acceleration", "xl"},
                 "gyro": {"g", "gyr", "gyro", "gyroscope", "angularvelocity"}}
_RATE_UNITS = {"hz": 1.0, "khz": 1e3, "sps": 1.0, "sampless": 1.0, "samplespers": 1.0}
_DURATION_UNITS = {**{k: TIME_UNITS[v] for k, v in TIME_UNIT_KEYS.items()},
                   "min": 60.0, "mins": 60.0, "minute": 60.0, "minutes": 60.0}
_VALUE = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(.*)$")


@dataclass
class FileFacts:
    """What a preamble stated, each with where it was read (``"'fs' (line 2)"``)."""

    rates: dict[str | None, tuple[float, str]] = field(default_factory=dict)  # sensor or None
    time_unit: tuple[str, str] | None = None
    init_still_s: tuple[float, str] | None = None
    unread: list[str] = field(default_factory=list)  # rate keys not understood or contradicting

    def rate_for(self, sensor: str) -> tuple[float, str] | None:
        return self.rates.get(sensor) or self.rates.get(None)

    def summary(self) -> str:
        said = [f"sample rate {rate:g} Hz{'' if s is None else ' (' + s + ')'} from {where}"
                for s, (rate, where) in self.rates.items()]
        if self.time_unit:
            said.append(f"time unit {self.time_unit[0]} from {self.time_unit[1]}")
        if self.init_still_s:
            said.append(f"initial still period {self.init_still_s[0]:g} s from "
                        f"{self.init_still_s[1]}")
        said += self.unread
        return "; ".join(said)


def read_facts(pairs: tuple[tuple[int, str, str], ...]) -> FileFacts:
    """The rate(s), time unit and initial still period the ``(line, key, value)`` pairs state."""
    facts = FileFacts()
    for line, key, value in pairs:
        words = unit_key_spaced(key.lower()).split()
        joined = "".join(words)
        where = f"{key.strip()!r} (line {line})"
        if not words or _OTHER_SENSORS & set(words):
            continue
        unit_word = _unit_in(words)
        if "unit" in words or "units" in words or joined in ("timeunit", "timeunits"):
            unit = TIME_UNIT_KEYS.get(unit_key_spaced(value.lower()).replace(" ", ""))
            if unit is not None and ("time" in joined or "stamp" in joined):
                facts.time_unit = facts.time_unit or (unit, where)
            continue
        number, value_unit = _number(value)
        is_rate, rate = _rate(words, joined, number, value_unit or unit_word)
        if _STILL_WORDS & set(words) or (_INIT_WORDS & set(words) and not is_rate):
            scale = _DURATION_UNITS.get(value_unit or unit_word or "s")
            if number is not None and scale is not None and number > 0:
                facts.init_still_s = facts.init_still_s or (number * scale, where)
            continue
        if not is_rate:
            continue
        if rate is None or not (0 < rate <= MAX_RATE_HZ):
            facts.unread.append(f"{where} = {value!r} is not understood as a rate")
            continue
        sensor = next((s for s, names in _SENSOR_WORDS.items() if names & set(words)), None)
        first = facts.rates.setdefault(sensor, (rate, where))
        if abs(rate / first[0] - 1) > 0.01:
            facts.unread.append(f"{where} states {rate:g} Hz, unlike {first[1]}; the first is "
                                "used")
    return facts


def _rate(words: list[str], joined: str, number: float | None, unit: str | None
          ) -> tuple[bool, float | None]:
    """Whether the key states a rate or a period, and the rate in Hz (None when the value
    makes no sense)."""
    is_rate = bool(_RATE_WORDS & set(words)) or any(w in joined for w in ("samplerate",
                                                                          "samplingrate"))
    is_period = bool(_PERIOD_WORDS & set(words)) or joined in _PERIOD_WORDS
    if not (is_rate or is_period):
        return False, None
    if number is None or not math.isfinite(number) or number <= 0:
        return True, None
    if is_period and not is_rate:
        scale = _DURATION_UNITS.get(unit or "s")
        return True, None if scale is None else 1.0 / (number * scale)
    scale = _RATE_UNITS.get(unit or "hz")
    return True, None if scale is None else number * scale


def _unit_in(words: list[str]) -> str | None:
    """A unit word in a key ("sample_rate_hz" -> "hz", "init_still_s" -> "s")."""
    for word in reversed(words[1:]):
        if word in _RATE_UNITS or word in _DURATION_UNITS:
            return word
    return None


def _number(value: str) -> tuple[float | None, str | None]:
    """The number at the start of a value and the unit after it ("200 Hz" -> 200, "hz")."""
    text = value.strip().strip("\"'")
    if text.count(",") == 1 and "." not in text:
        text = text.replace(",", ".")  # "102,4": a decimal comma
    match = _VALUE.match(text)
    if not match:
        return None, None
    unit = unit_key_spaced(match.group(2).lower()).replace(" ", "") or None
    return float(match.group(1)), unit
