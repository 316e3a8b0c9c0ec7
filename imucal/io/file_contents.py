"""What a reader makes of a file (method.md §0): a table of columns, or named variables.

Both are raw material: which columns or variables hold time, the accelerometer and the
gyroscope is decided by :mod:`imucal.io.load`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np


@dataclass
class Table:
    """Columns of a text or Parquet file, or one matrix; converted to float64 on demand."""

    source: str
    names: list[str] | None  # None: no header, columns are known by position
    n_cols: int
    column: Callable[[int], np.ndarray]
    seconds_cols: frozenset[int] = frozenset()  # date-times already turned into seconds
    shared_time: np.ndarray | None = None  # a separate time vector next to a .mat matrix
    shared_time_name: str = ""
    # ``key<sep>value`` lines above the table (and in its comments), as (line, key, value):
    # what a logger says of its recording (rate, time unit, initial still period)
    preamble: tuple[tuple[int, str, str], ...] = ()
    notes: tuple[str, ...] = ()  # what the reader did that the user should know (a cut line)
    # ``np.column_stack`` of some columns, where a reader makes them its own way (a long text
    # file's, into the spill: :mod:`imucal.io.text_pieces`); None: numpy's
    stack: Callable[[list[int]], np.ndarray] | None = None

    def columns(self, cols: list[int]) -> np.ndarray:
        """The columns ``cols`` side by side, (N, len(cols)) float64."""
        if self.stack is not None:
            return self.stack(cols)
        return np.column_stack([self.column(c) for c in cols])

    def label(self, i: int) -> str:
        return f"column {self.names[i]!r}" if self.names else f"column {i + 1}"


@dataclass
class Variables:
    """Named numeric variables of a .mat (v5 or v7.3) file, as 2-D float64 arrays."""

    source: str
    arrays: dict[str, np.ndarray]
    # The variables that are not real numeric matrices, and what each is ("a sparse matrix"):
    # named when one of them is where the accelerometer or gyroscope was expected.
    skipped: dict[str, str] = field(default_factory=dict)
