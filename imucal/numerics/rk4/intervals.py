"""Many intervals of a sampled body rate, passed to the compiled kernels (:mod:`.kernels`,
method.md M5) where the samples lie, or gathered a chunk of intervals at a time.

A float64 ndarray (strided or memory-mapped alike) is read by the kernels in place: nothing is
copied. Any other array (one kept on disk that offers only ``len``, ``.shape`` and gathers of
rows with a 1-D integer array, or samples of another dtype) is gathered a chunk of whole
intervals at a time into compact float64 arrays, which the same kernels read through offsets:
the same arithmetic on the same values, so the same numbers to the bit.

numba is imported by the first pass, not with this module (a run that integrates nothing does
not pay for it).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import NamedTuple

import numpy as np

# Rows gathered at once from an array that is not read in place: whole intervals up to this
# many rows (2 MB of float64 samples and timestamps); an interval longer than that is gathered
# alone.
CHUNK_ROWS = 1 << 16


def _kernels():
    from imucal.numerics.rk4 import kernels

    return kernels


def _in_place(x, ndim: int) -> bool:
    """Whether the kernels read ``x`` where it lies: a writeable float64 ndarray (numba types a
    read-only array apart, and the kernels are compiled for one type)."""
    return (isinstance(x, np.ndarray) and x.dtype == np.float64 and x.ndim == ndim
            and x.flags.writeable)


def chunks(lengths: np.ndarray, rows: int) -> list[tuple[int, int]]:
    """Consecutive runs ``k0 .. k1 - 1`` of intervals of ``lengths`` rows, each of at most
    ``rows`` rows in all unless one interval alone is longer."""
    out: list[tuple[int, int]] = []
    k0, total = 0, 0
    for k, n in enumerate(lengths.tolist()):
        if k > k0 and total + n > rows:
            out.append((k0, k))
            k0, total = k, 0
        total += n
    if k0 < len(lengths):
        out.append((k0, len(lengths)))
    return out


class Sensitivity(NamedTuple):
    """One pass under a model: ``q`` (K, 4) every interval's rotation (the same to the bit as
    :meth:`Intervals.integrate` gives) and ``S`` (K, 3, 3, 4) its sensitivity
    (:func:`.kernels.sensitivity`)."""

    q: np.ndarray
    S: np.ndarray


class Intervals:
    """Interval k: samples ``starts[k] .. ends[k]`` of the rates ``x`` (N, 3) at the strictly
    increasing times ``t`` (N,), ``ends[k] - starts[k]`` RK4 steps on the real timestamps (none:
    the identity). The rate model is ``w = M (x - b)`` (method.md M4)."""

    def __init__(self, x, t, starts: np.ndarray, ends: np.ndarray):
        self.x, self.t = x, t
        self.starts = np.ascontiguousarray(starts, np.int64)
        self.ends = np.ascontiguousarray(ends, np.int64)
        self.in_place = _in_place(x, 2) and _in_place(t, 1)
        self.chunks = [] if self.in_place else chunks(self.ends - self.starts + 1, CHUNK_ROWS)

    def __len__(self) -> int:
        return len(self.starts)

    def _parts(self) -> Iterator[tuple[slice, object, object, np.ndarray, np.ndarray]]:
        """Each chunk: the intervals (a slice), the rows the kernels read and the intervals'
        first and last rows in them."""
        if self.in_place:
            if len(self):
                yield slice(0, len(self)), self.x, self.t, self.starts, self.ends
            return
        for k0, k1 in self.chunks:
            s, e = self.starts[k0:k1], self.ends[k0:k1]
            lengths = e - s + 1
            first = np.cumsum(lengths) - lengths  # each interval's first row in the chunk
            idx = np.repeat(s - first, lengths) + np.arange(int(lengths.sum()))
            x = np.ascontiguousarray(self.x[idx], np.float64).reshape(len(idx), -1)
            t = np.ascontiguousarray(self.t[idx], np.float64)
            yield slice(k0, k1), x, t, first, first + (e - s)

    def integrate(self, M: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Every interval's rotation (k, K, 4), normalised, under each of k models ``M[m]``
        (3, 3), ``b[m]`` (3,) at once (each model's numbers the same as alone)."""
        M, b = _models(M, b)
        out = np.empty((len(M), len(self), 4))
        kern = _kernels().integrate
        for part, x, t, s, e in self._parts():
            kern(x, t, s, e, M, b, out[:, part])
        return out

    def integrate_each(self, M: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Every interval's rotation (K, 4) under a model of its own, ``M[k]`` (3, 3) and
        ``b[k]`` (3,) for interval k."""
        M, b = _models(M, b)
        out = np.empty((len(self), 4))
        kern = _kernels().integrate_each
        for part, x, t, s, e in self._parts():
            kern(x, t, s, e, M[part], b[part], out[part])
        return out

    def sensitivity(self, M: np.ndarray, b: np.ndarray) -> Sensitivity:
        """Every interval's rotation and ``S`` (:func:`.kernels.sensitivity`) under one model."""
        M, b = np.ascontiguousarray(M, np.float64), np.ascontiguousarray(b, np.float64)
        q, S = np.empty((len(self), 4)), np.empty((len(self), 9, 4))
        kern = _kernels().sensitivity
        for part, x, t, s, e in self._parts():
            kern(x, t, s, e, M, b, q[part], S[part])
        return Sensitivity(q, S.reshape(len(self), 3, 3, 4))

    def max_step(self, M: np.ndarray, b: np.ndarray) -> float:
        """The largest angle turned in one step (:func:`.kernels.max_step`; 0 without steps)."""
        M, b = np.ascontiguousarray(M, np.float64), np.ascontiguousarray(b, np.float64)
        kern = _kernels().max_step
        return max((kern(x, t, s, e, M, b) for _, x, t, s, e in self._parts()), default=0.0)

    def raw_turn(self, b: np.ndarray) -> np.ndarray:
        """Integral of ``|x - b|`` over each interval (K,) (:func:`.kernels.raw_turn`)."""
        b = np.ascontiguousarray(b, np.float64)
        out = np.empty(len(self))
        kern = _kernels().raw_turn
        for part, x, t, s, e in self._parts():
            kern(x, t, s, e, b, out[part])
        return out


def _models(M: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return np.ascontiguousarray(M, np.float64), np.ascontiguousarray(b, np.float64)


def integrate_transitions(w: np.ndarray, t: np.ndarray, starts: np.ndarray, ends: np.ndarray
                          ) -> np.ndarray:
    """Body rotation over each interval ``[t[starts[k]], t[ends[k]]]`` from q = identity.

    ``w`` (N, 3) calibrated rates in rad/s at times ``t`` (N,); interval k takes
    ``ends[k] - starts[k]`` RK4 steps on the real timestamps. Returns (K, 4) quaternions.
    """
    return Intervals(w, t, starts, ends).integrate(np.eye(3)[None], np.zeros((1, 3)))[0]
