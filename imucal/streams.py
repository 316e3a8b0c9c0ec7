"""A recording of many sensor streams (method.md §0, widened): what a log holds before anything is
chosen to calibrate.

A log of a real device holds more than one accelerometer and one gyroscope: two or three IMUs, a
magnetometer, a thermometer, each on its own clock, at its own rate, in its own unit and frame.
A :class:`Stream` is one of them as the source states it; a :class:`StreamSet` is every stream of
one file. The calibration path then takes one accelerometer and one gyroscope from it
(:func:`imucal.io.select.session_from_streams`) into the :class:`~imucal.session.Session` the
stages have always used, so a one-IMU file gives the same session, and the same result, as before.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# The kinds of stream, and the number of columns each holds.
KINDS = ("acc", "gyro", "mag", "temp")
WIDTH = {"acc": 3, "gyro": 3, "mag": 3, "temp": 1}
KIND_LABELS = {"acc": "accelerometer", "gyro": "gyroscope", "mag": "magnetometer",
               "temp": "temperature"}
# Units a stream may state. None: the source does not say (the loader guesses, as for tables).
UNITS = {
    "acc": ("g", "m/s^2", "counts"),
    "gyro": ("rad/s", "deg/s", "counts"),
    "mag": ("gauss", "uT", "mG", "T", "counts", "normalised"),
    "temp": ("degC",),
}


@dataclass(frozen=True)
class Stream:
    """One sensor's samples as a source states them.

    ``values`` is (N, 3) for a triad (N, 1 for a temperature), float64, in ``unit``; ``t`` is
    (N,) in seconds on the source's own clock, increasing (a reader sorts and drops repeated
    stamps and says so in ``notes``). ``instance`` names the stream within its kind the way the
    source does: a ROS topic (``/imu/data_raw``), a ULog topic and instance
    (``sensor_accel:1``), a DataFlash message (``IMU2``), an HDF5 path, a column prefix. ``frame``
    is the axis convention the source states (e.g. ``"FLU (ROS REP 103)"``, ``"FRD (PX4
    body)"``), None where it states none. ``origin`` says where in the file it came from, and
    ``time_source`` which clock was used (header stamps, receive time, a timestamp field).
    ``device`` is what the source says identifies the sensor (a PX4 device_id, a frame_id).
    ``imu`` names the IMU the stream belongs to: an accelerometer and a gyroscope that share it
    come from one unit (one ``sensor_msgs/Imu`` topic, one DataFlash ``IMU2``, one ULog
    instance) and are what a calibration takes together by default.
    """

    kind: str
    instance: str
    t: np.ndarray
    values: np.ndarray
    unit: str | None
    origin: str
    frame: str | None = None
    time_source: str = ""
    device: str | None = None
    imu: str | None = None
    notes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"kind must be one of {KINDS}, got {self.kind!r}")
        if self.unit is not None and self.unit not in UNITS[self.kind]:
            raise ValueError(f"a {self.kind} stream's unit must be one of {UNITS[self.kind]} or "
                             f"None, got {self.unit!r}")
        if self.values.ndim != 2 or self.values.shape[1] != WIDTH[self.kind]:
            raise ValueError(f"a {self.kind} stream holds (N, {WIDTH[self.kind]}) values, got "
                             f"{self.values.shape}")
        if self.t.shape != (len(self.values),):
            raise ValueError(f"one timestamp per sample expected ({len(self.values)}), got "
                             f"{self.t.shape}")

    @property
    def name(self) -> str:
        """How the stream is named to a user and chosen with a selector: ``acc /imu/data_raw``."""
        return f"{self.kind} {self.instance}"

    @property
    def samples(self) -> int:
        return len(self.t)

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0]) if len(self.t) > 1 else 0.0

    @property
    def rate(self) -> float | None:
        """The median sample rate (Hz); None below two samples or with a zero median step."""
        if len(self.t) < 2:
            return None
        step = float(np.median(np.diff(self.t)))
        return 1.0 / step if step > 0 else None

    def gaps(self, factor: float = 3.0) -> int:
        """Steps longer than ``factor`` median steps: samples the source lost."""
        if len(self.t) < 3:
            return 0
        steps = np.diff(self.t)
        return int(np.count_nonzero(steps > factor * float(np.median(steps))))


@dataclass(frozen=True)
class StreamSet:
    """Every stream one file holds, in the order the source lists them, and what its reader
    noticed (``notes``). ``format`` names the file's format for the user (``"ROS 1 bag"``)."""

    source: str
    format: str
    streams: tuple[Stream, ...]
    sha256: str = ""
    notes: tuple[str, ...] = field(default_factory=tuple)

    def of_kind(self, kind: str) -> tuple[Stream, ...]:
        return tuple(s for s in self.streams if s.kind == kind)

    def kinds(self) -> tuple[str, ...]:
        return tuple(k for k in KINDS if self.of_kind(k))


def first_of_kind(streams: tuple[Stream, ...], kind: str) -> Stream | None:
    """The first stream of ``kind``: the magnetometer a calibration takes beside its pair is
    the first of the session's other streams (the one ``--mag`` names is put first)."""
    return next((s for s in streams if s.kind == kind), None)
