"""A signal's logged rows (:mod:`viewer.decimate`'s min/max envelope) made a chunk of rows at a
time, in memory bounded by a chunk (issue 12: a 6-hour 1 kHz session's calibrated signals
alone are 1 GB, and were made whole only to be cut into 20 000 rows).

The rows are the same as the whole signal's, to the bit: a bucket is made only once all its
samples are in (the samples fed past the last complete bucket wait for the next chunk), and it
is made by the same :func:`~viewer.decimate.run_envelope` from the same samples. Only where
the chunks end differs, and no bucket sees it. :func:`magnitudes_for_display` is the whole
signal fed at once. This module builds on :mod:`viewer.decimate` (the cuts and the envelope),
never the other way round.
"""

from __future__ import annotations

import numpy as np

from imucal.numerics.windows import runs_of_true

from .decimate import Cut, Decimation, magnitude_cut, run_envelope


class EnvelopeStream:
    """The rows of one signal on the time axis ``t``, cut as ``cut`` says; :meth:`feed` it the
    signal's rows in order, in chunks of any length, then read :meth:`rows`."""

    def __init__(self, t: np.ndarray, cut: Cut) -> None:
        self.t, self.cut = t, cut
        self.n = cut.decimation.samples
        self.done = 0  # rows [0, done) are in the envelope
        self.waiting: np.ndarray | None = None  # rows [done, fed): a bucket not yet complete
        self.fed = 0
        self.parts: list[tuple[np.ndarray, np.ndarray]] = []

    def feed(self, x: np.ndarray) -> None:
        """The next ``len(x)`` rows of the signal ((k,) or (k, m), one dtype throughout)."""
        self.fed += len(x)
        if self.waiting is not None and len(self.waiting):
            x = np.concatenate([self.waiting, x])
        end = self._complete(self.fed)
        k = end - self.done
        if k > 0:
            self.parts.append(self._envelope(self.done, end, x[:k]))
        self.waiting = x[k:].copy()  # at most a bucket: the chunk itself is not kept
        self.done = end

    def rows(self) -> tuple[np.ndarray, np.ndarray, Decimation]:
        """The times, the values and what was chosen (``rows`` filled in), once every row has
        been fed."""
        if self.fed != self.n or self.done != self.n:
            raise ValueError(f"{self.fed} of {self.n} rows fed")
        if not self.parts:
            return self.t[:0], np.zeros(0), self.cut.decimation
        t = np.concatenate([p[0] for p in self.parts])
        v = np.concatenate([p[1] for p in self.parts])
        d = self.cut.decimation
        return t, v, Decimation(d.samples, len(t), d.still_bucket, d.moving_bucket)

    def _complete(self, fed: int) -> int:
        """The end of the last bucket wholly inside ``[0, fed)``."""
        if fed >= self.n:
            return self.n
        runs = self.cut.runs
        r = int(np.searchsorted(runs[:, 0], fed, side="right")) - 1
        start, size = int(runs[r, 0]), int(self.cut.size[r])
        return start + (fed - start) // size * size

    def _envelope(self, a: int, b: int, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rows of samples ``[a, b)`` (``x``), both ends a bucket's edge: the runs clipped to
        them keep their buckets. Runs of each bucket size together (one vectorised envelope),
        then in time order, as :func:`magnitudes_for_display` orders them."""
        runs, sizes = self.cut.runs, self.cut.size
        r0 = int(np.searchsorted(runs[:, 1], a, side="right"))
        r1 = int(np.searchsorted(runs[:, 0], b, side="left"))
        local = np.clip(runs[r0:r1], a, b) - a
        local_size = sizes[r0:r1]
        t = self.t[a:b]
        parts = [run_envelope(t, x, local[local_size == s], int(s))
                 for s in np.unique(local_size)]
        if len(parts) == 1:
            return parts[0]
        tt = np.concatenate([p[0] for p in parts])
        order = np.argsort(tt, kind="stable")  # the times are strictly increasing: run order
        return tt[order], np.concatenate([p[1] for p in parts])[order]


def magnitudes_for_display(t: np.ndarray, v: np.ndarray, still: np.ndarray, keep_still: bool
                           ) -> tuple[np.ndarray, np.ndarray, Decimation]:
    """Magnitudes as logged: with ``keep_still`` the still samples as they are while there are
    at most ``STILL_ROWS`` of them (else an envelope of about that many rows), without it an
    envelope of about ``SCREEN_ROWS`` rows there too (the gyroscope); the samples between the
    blocks an envelope of about ``SCREEN_ROWS`` rows (:mod:`viewer.decimate` says why). No
    bucket crosses a block's edge.

    The whole signal at once; :class:`EnvelopeStream` makes the same rows a chunk at a time."""
    cut = magnitude_cut(runs_of_true(np.asarray(still, bool)), len(t), keep_still)
    d = cut.decimation
    if d.still_bucket == 1 and d.moving_bucket == 1:
        return t, v, Decimation(len(t), len(t), 1, 1)
    stream = EnvelopeStream(t, cut)
    stream.feed(v)
    return stream.rows()
