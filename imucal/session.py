"""The session: raw accelerometer and gyroscope signals with their timestamps and units."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

ACC_UNITS = ("g", "m/s^2", "counts")
GYRO_UNITS = ("rad/s", "deg/s", "counts")
STANDARD_GRAVITY = 9.80665


@dataclass(frozen=True)
class Session:
    """A recording to calibrate (method.md §0).

    ``acc`` is (N, 3) with timestamps ``t_acc`` (N,) in seconds, strictly increasing; ``gyro``
    is (M, 3) with ``t_gyro`` (M,), or both ``None`` for an accelerometer-only session. The
    two sensors may run at different rates. Gyroscope data given in deg/s is converted to rad/s
    on load, so ``gyro_unit`` is ``"rad/s"`` or ``"counts"``.
    """

    acc: np.ndarray
    t_acc: np.ndarray
    gyro: np.ndarray | None = None
    t_gyro: np.ndarray | None = None
    acc_unit: str = "g"
    gyro_unit: str | None = "rad/s"
    source: str = "<memory>"
    sha256: str = ""
    notes: tuple[str, ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        if self.acc_unit not in ACC_UNITS:
            raise ValueError(f"acc_unit must be one of {ACC_UNITS}, got {self.acc_unit!r}")
        if self.gyro is not None and self.gyro_unit not in ("rad/s", "counts"):
            raise ValueError(f"gyro_unit must be 'rad/s' or 'counts', got {self.gyro_unit!r}")

    @property
    def has_gyro(self) -> bool:
        return self.gyro is not None and len(self.gyro) > 0

    @property
    def acc_rate(self) -> float:
        """Median sample rate of the accelerometer in Hz."""
        return float(1.0 / np.median(np.diff(self.t_acc)))

    @property
    def gyro_rate(self) -> float | None:
        if not self.has_gyro:
            return None
        return float(1.0 / np.median(np.diff(self.t_gyro)))

    @property
    def duration(self) -> float:
        return float(self.t_acc[-1] - self.t_acc[0])
