"""What the layouts hand the time base: one sensor's samples as read, before time and units
are settled, and the load options every step consults."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from imucal.errors import ImucalError
from imucal.io.column_names import AXES


@dataclass
class Part:
    """One sensor's samples as read from a file, before time and units are settled."""

    sensor: str  # "acc" or "gyro"
    source: str
    values: np.ndarray  # (N, 3) float64
    time: np.ndarray | None = None  # in the file's units
    time_label: str = ""
    time_unit: str | None = None  # named by the file (e.g. a column "time_ms")
    time_unit_from: str = "as its name says"  # where time_unit comes from, for the notes
    time_is_datetime: bool = False  # converted from date-times: seconds whatever time_unit says
    unit_hint: str | None = None
    counter_label: str | None = None  # a sample-counter column, to explain a missing rate
    stated_rate: tuple[float, str] | None = None  # Hz the file's preamble states, and where


@dataclass
class LoadOptions:
    rate: float | None
    time_unit: str
    columns: dict[str, str | int] | None
    notes: list[str] = field(default_factory=list)
    init_still_s: float | None = None  # the initial still period a file states
    # Streams a table holds beside the calibrated pair (a2x…, g2x…, mx…, temp): (kind, part),
    # the part's ``sensor`` naming the instance ("a2", "m", "temp").
    extras: list[tuple[str, Part]] = field(default_factory=list)
    number_samples: bool = False  # no time and no rate: t = 0, 1, 2, ... (load_session)


def columns_for(opts: LoadOptions, sensors: tuple[str, ...], source: str
                ) -> dict[str, str | int]:
    """The part of ``columns`` that concerns this file: in a two-file session the accelerometer
    file takes t, ax, ay, az and the gyroscope file t, gx, gy, gz."""
    roles = {"t", *(r for s in sensors for r in AXES[s])}
    mine = {role: col for role, col in (opts.columns or {}).items() if role in roles}
    values = list(mine.values())
    dupes = sorted({str(v) for v in values if values.count(v) > 1})
    if dupes:
        raise ImucalError(f"column(s) {', '.join(dupes)} mapped to more than one role",
                          source=source, field="columns")
    return mine
