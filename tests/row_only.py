"""A signal as a disk-backed session array offers it, and nothing more: ``len``, ``shape``,
``ndim``, ``dtype``, contiguous row slices ``x[a:b]`` / ``x[a:b, j]`` (a fresh C-ordered array)
and integer-array gathers ``x[idx]``. Anything else (``np.asarray(x)``, a strided slice, a
scalar index, iteration) raises, so a stage that reads the signal otherwise fails its test.
It also counts what was read: the largest slice and the rows read in all."""

from __future__ import annotations

import numpy as np


class RowOnly:
    def __init__(self, x: np.ndarray):
        self._x = np.asarray(x)
        self.largest = 0  # rows of the largest slice or gather
        self.rows_read = 0

    def __len__(self) -> int:
        return len(self._x)

    @property
    def shape(self) -> tuple[int, ...]:
        return self._x.shape

    @property
    def ndim(self) -> int:
        return self._x.ndim

    @property
    def dtype(self) -> np.dtype:
        return self._x.dtype

    def _count(self, rows: int) -> None:
        self.largest = max(self.largest, rows)
        self.rows_read += rows

    def __getitem__(self, key):
        if isinstance(key, slice):
            return self._slice(key)
        if (isinstance(key, tuple) and len(key) == 2 and isinstance(key[0], slice)
                and isinstance(key[1], (int, np.integer)) and self.ndim == 2):
            return np.array(self._slice(key[0])[:, key[1]], order="C")
        if isinstance(key, np.ndarray) and key.ndim == 1 and key.dtype.kind in "iu":
            self._count(len(key))
            return np.array(self._x[key], order="C")
        raise TypeError(f"a disk-backed array has no index {key!r}")

    def _slice(self, key: slice) -> np.ndarray:
        if key.step not in (None, 1):
            raise TypeError("a disk-backed array has no strided slices")
        a, b, _ = key.indices(len(self._x))
        self._count(max(b - a, 0))
        return np.array(self._x[a:b], order="C")

    def __array__(self, *args, **kwargs):
        raise TypeError("np.asarray would read the whole disk-backed array")

    def __iter__(self):
        raise TypeError("a disk-backed array is not iterated")
