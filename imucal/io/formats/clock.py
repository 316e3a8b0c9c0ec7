"""A log's clock as the streams need it: increasing stamps, each once (method.md §0).

Loggers write messages in the order they receive them, and a driver may stamp two messages
alike; a stream's time must increase strictly. Shared by every format's reader.
"""

from __future__ import annotations

import numpy as np

from imucal.errors import plural


def in_time_order(stamps: np.ndarray, name: str, notes: list[str], unit: str = "message"
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The stamps sorted with repeats dropped (the first of each kept), and the indices into
    ``stamps`` of what is kept; what was done is said in ``notes`` under ``name``."""
    order = np.argsort(stamps, kind="stable")
    if (np.diff(order) != 1).any():
        notes.append(f"{name}: {unit}s not in time order; sorted")
    ordered = stamps[order]
    first = np.ones(len(ordered), dtype=bool)
    first[1:] = ordered[1:] != ordered[:-1]
    if not first.all():
        notes.append(f"{name}: {plural(int((~first).sum()), 'repeated stamp')} dropped "
                     f"(the first {unit} of each stamp kept)")
    return ordered[first], order[first]
