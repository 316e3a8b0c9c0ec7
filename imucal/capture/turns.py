"""The gyroscope samples of one turn between two holds, kept in bounded memory for the running
gyroscope fit of a live capture (method.md §13).

A turn runs from the last two still samples of a hold to the first two of the next (the samples
M5's integration starts and ends on: :func:`imucal.stages.gyro_transitions.transition_samples`).
Those four are kept as they came; the samples between them go into at most ``cap`` rows: when
the rows are full, each pair of neighbours becomes one row (the mean of their times and of their
rates) and the rows that follow average twice as many samples. The integral of the rate, what
M5 turns gravity with, is kept exactly; only the change of the axis within a merged pair
(coning, second order) is lost. A turn of ``cap`` samples or fewer (4 s at 1 kHz) is kept
exactly; each merge costs O(cap) once per ``cap / 2`` rows, so O(1) per sample.
"""

from __future__ import annotations

import numpy as np

MAX_TURN_SAMPLES = 4096  # rows a turn keeps between its ends (128 kB)


class TurnBuffer:
    """One turn's rows of (t, wx, wy, wz), its ends as received, its middle decimated."""

    def __init__(self, head: np.ndarray, cap: int = MAX_TURN_SAMPLES) -> None:
        self.head = np.asarray(head, dtype=np.float64).reshape(-1, 4)[-2:]  # the hold's end
        self.cap = cap - cap % 2
        self.body = np.empty((self.cap, 4))
        self.n = 0  # rows of body in use
        self.factor = 1  # samples each new row averages
        self.part_sum = np.zeros(4)  # samples of the row being filled
        self.part_n = 0
        self.samples = 0  # samples received (the turn's length as it came)

    def add(self, rows: np.ndarray) -> None:
        """Append samples (N, 4): t, wx, wy, wz."""
        rows = np.asarray(rows, dtype=np.float64).reshape(-1, 4)
        self.samples += len(rows)
        f = self.factor
        while len(rows):
            room = (self.cap - self.n) * f - self.part_n  # samples until the rows are full
            take, rows = rows[:room], rows[room:]
            full = (self.part_n + len(take)) // f  # rows this completes
            if full:
                need = full * f - self.part_n
                starts = np.r_[0, np.arange(f - self.part_n, need, f)]
                sums = np.add.reduceat(take[:need], starts, axis=0)
                sums[0] += self.part_sum
                self.body[self.n:self.n + full] = sums / f
                self.n += full
                rest = take[need:]
                self.part_sum, self.part_n = rest.sum(axis=0), len(rest)
            else:
                self.part_sum = self.part_sum + take.sum(axis=0)
                self.part_n += len(take)
            if self.n == self.cap:  # full: pairs of rows become one
                self.body[: self.cap // 2] = 0.5 * (self.body[0::2] + self.body[1::2])
                self.n = self.cap // 2
                f = self.factor = 2 * f

    def finish(self, before: float, tail: np.ndarray) -> np.ndarray:
        """The turn's rows (M, 4): the head, the middle up to time ``before`` (the next hold's
        first still sample: rows from its start on are dropped, they were that hold) and the
        ``tail`` (its first two samples)."""
        keep = int(np.searchsorted(self.body[: self.n, 0], before, side="left"))
        parts = [self.head, self.body[:keep]]
        if self.part_n and self.part_sum[0] / self.part_n < before:
            parts.append((self.part_sum / self.part_n)[None, :])
        parts.append(np.asarray(tail, dtype=np.float64).reshape(-1, 4)[:2])
        return np.vstack(parts)

    @property
    def nbytes(self) -> int:
        return self.body.nbytes + self.head.nbytes
