"""How many rows a signal gets in the recording: as many as a screen can show, plus the still
samples of the accelerometer's magnitude at full rate up to a bound.

Why bounded. The viewer holds every logged row in memory and, for every frame, walks every row
of a plot's visible range; its picture settles only once it has drawn them all. Measured
(``bench/viewer_open.md``, headless native viewer, minimums of repeated opens): with the
per-axis plots at 100 000 rows and both magnitudes at full rate in the still blocks, a 60-minute
1 kHz session took 6.9x the sample's time to settle and 2.5x its memory, a 2-hour one 22x and
3.6x. A plot is at most ~1600 pixels wide, so more than a few min/max pairs per pixel column
cannot be seen until one zooms in: past ``SCREEN_ROWS`` samples a signal is drawn as a min/max
envelope of that many rows, whatever the session's length. With the bounds below both open in
1.1x the sample's time and memory.

What stays at full rate, and why only that.

- The accelerometer's magnitude inside the still blocks, raw and calibrated: that is where the
  method looks (M3 fits ``|g| - |T K (a - b)|`` to the still blocks) and where a person judges
  the calibration to the milli-g, zooming into a block to see its noise around ``|g|``. Every
  such sample is logged as it is, up to ``STILL_ROWS`` of them (~200 s of 1 kHz data: every
  still sample of a session up to ~6 minutes at 1 kHz or ~1 hour at 100 Hz, the sample's
  rate). Past that the still blocks alone (an hour of 1 kHz data in a 2-hour session) are what
  the viewer chokes on: measured, keeping them all (everything else bounded) took the 60- and
  120-minute sessions to 3.2x and 7.2x the sample's time (1.8x, 2.5x its memory), a bound of
  1 000 000 to 2.3x and 1.9x. So past ``STILL_ROWS`` they become a min/max envelope too, of
  buckets made as small as that allows, each inside one block (18 samples, 18 ms, for the
  60-minute session; 35 for the 2-hour one: still ~70 min/max pairs in its median 2.4 s
  block): every block's noise band and extremes are kept exactly, and its mean, the number the
  fit uses, is logged at full precision per block (``blocks/norm_error_mg``). What
  was chosen is recorded beside the signal (:class:`Decimation`, AnyValues on its entity).
- Everything else is a min/max envelope: the per-axis plots of both sensors and the detector's
  statistic (``SCREEN_ROWS`` over the whole session: shapes, turns and peaks, nothing judged
  to the sample), the magnitudes between the blocks, and the gyroscope's magnitude in the
  blocks too (the method uses the gyroscope's still samples only through their mean, the bias
  ``b_g`` of M4; its fit is judged by the gravity angles of M5, logged per block). Buckets
  never straddle a block's edge, so a block starts and ends where it does and its envelope
  holds only still samples.

An envelope: consecutive samples are cut into buckets of one size; each bucket becomes two rows
which hold, per column, the bucket's minimum and maximum in the order they occur (so a rise
stays a rise), stamped with the times of the bucket's first and middle sample: a peak is drawn
at most one bucket away from where it happened, and never lost. Vectorised: no loop over
buckets or runs. A :class:`Cut` says how a signal is cut; :mod:`viewer.stream` makes its rows
from the signal given a chunk at a time (a long session's signals are never read whole).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# A plot is ~1600 pixels wide at most: 10 000 min/max buckets leave ~6 per pixel column, so
# zooming in 6x still shows every extreme before the envelope's steps show.
SCREEN_ROWS = 20_000
# The accelerometer's still samples kept at full rate, at most: ~200 s of 1 kHz data. Chosen
# by measurement (bench/viewer_open.md) as what the viewer opens in about the sample's time.
STILL_ROWS = 200_000

# Kept for scripts that read the old names: a signal longer than this is an envelope of at
# most this many rows.
DECIMATE_ABOVE = ENVELOPE_ROWS = SCREEN_ROWS


@dataclass(frozen=True)
class Decimation:
    """What one logged signal is: ``rows`` logged from ``samples``; inside the still blocks
    ``still_bucket`` samples per min/max pair (1: every sample as it is), outside them
    ``moving_bucket`` (1: every sample)."""

    samples: int
    rows: int
    still_bucket: int
    moving_bucket: int


def for_display(t: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A per-axis signal as it is logged: itself, or its envelope past ``SCREEN_ROWS``."""
    return envelope(t, x, SCREEN_ROWS)


@dataclass(frozen=True)
class Cut:
    """How a signal of ``samples`` rows is cut into buckets: ``runs`` ``[start, end)`` that
    cover ``[0, samples)`` in order, run i in buckets of ``size[i]`` samples (1: the samples as
    they are). ``decimation`` is what is recorded beside it (its ``rows`` counted as made)."""

    runs: np.ndarray  # (R, 2) int64
    size: np.ndarray  # (R,) int64
    decimation: Decimation


def axes_cut(n: int) -> Cut:
    """A per-axis signal (and the detector's statistic): as it is up to ``SCREEN_ROWS``
    samples, else one envelope of at most that many rows (:func:`for_display`)."""
    runs = np.array([[0, n]], np.int64)
    size = 1 if n <= SCREEN_ROWS else bucket_size(runs, SCREEN_ROWS)
    return Cut(runs, np.array([size], np.int64), Decimation(n, 0, size, size))


def magnitude_cut(still_runs: np.ndarray, n: int, keep_still: bool) -> Cut:
    """A magnitude's cut (:func:`viewer.stream.magnitudes_for_display`): ``still_runs`` the
    still samples' ``[start, end)`` ranges, in any order, overlapping or touching (they are
    merged, as a mask of them would be: :func:`union_runs`); the gaps between them are the
    moving runs."""
    still = union_runs(still_runs, n)
    moving = gaps(still, n)
    still_rows = STILL_ROWS if keep_still else SCREEN_ROWS
    n_still = int((still[:, 1] - still[:, 0]).sum())
    s_size = 1 if n_still <= still_rows else bucket_size(still, still_rows)
    m_size = 1 if n - n_still <= SCREEN_ROWS else bucket_size(moving, SCREEN_ROWS)
    runs = np.concatenate([still, moving])
    size = np.repeat(np.array([s_size, m_size], np.int64), [len(still), len(moving)])
    order = np.argsort(runs[:, 0], kind="stable")
    return Cut(runs[order], size[order], Decimation(n, 0, s_size, m_size))


def union_runs(runs: np.ndarray, n: int) -> np.ndarray:
    """The ``[start, end)`` runs (``start <= end``) of ``runs_of_true(mask_of_runs(runs, n))``
    without the mask: clipped to ``[0, n)``, empty ones dropped, overlapping or touching ones
    merged, sorted."""
    r = np.clip(np.asarray(runs, np.int64).reshape(-1, 2), 0, n)
    r = r[r[:, 1] > r[:, 0]]
    if len(r) == 0:
        return np.zeros((0, 2), np.int64)
    r = r[np.argsort(r[:, 0], kind="stable")]
    reach = np.maximum.accumulate(r[:, 1])  # the furthest end so far
    first = np.concatenate([[True], r[1:, 0] > reach[:-1]])  # starts a new merged run
    group_end = np.maximum.reduceat(r[:, 1], np.flatnonzero(first))
    return np.column_stack([r[first, 0], group_end])


def gaps(runs: np.ndarray, n: int) -> np.ndarray:
    """The ``[start, end)`` ranges of ``[0, n)`` outside the sorted, disjoint, non-touching
    ``runs`` (what ``runs_of_true(~mask)`` gives)."""
    edges = np.concatenate([[0], runs.ravel(), [n]]).reshape(-1, 2)
    return edges[edges[:, 1] > edges[:, 0]].astype(np.int64)


def envelope(t: np.ndarray, x: np.ndarray, max_rows: int) -> tuple[np.ndarray, np.ndarray]:
    """``(t, x)`` itself when it has at most ``max_rows`` rows, else its min/max envelope.

    ``x`` is (N,) or (N, k); the result has at most ``max_rows`` rows (and at least 2 when
    decimated) and the same number of columns.
    """
    n = len(t)
    if n <= max_rows:
        return t, x
    return run_envelope(t, x, np.array([[0, n]]), bucket_size(np.array([[0, n]]), max_rows))


def bucket_size(runs: np.ndarray, max_rows: int) -> int:
    """The smallest bucket size (samples) that cuts the ``[start, end)`` runs into at most
    ``max_rows / 2`` buckets, each inside one run; at least one bucket per run however small
    the budget (then 2 rows per run: a block stays a block)."""
    lengths = runs[:, 1] - runs[:, 0]
    if len(lengths) == 0:
        return 1
    budget = max(max_rows // 2, 1)
    if budget <= len(lengths):
        return int(lengths.max())
    # The bucket count falls as the size grows; sum(ceil(L / s)) <= sum(L) / s + runs makes
    # ``hi`` fit and nothing below sum(L) / budget can: bisect between the two.
    total = int(lengths.sum())
    lo, hi = max(-(-total // budget), 1), max(-(-total // (budget - len(lengths))), 1)
    while lo < hi:
        mid = (lo + hi) // 2
        if int((-(-lengths // mid)).sum()) <= budget:
            hi = mid
        else:
            lo = mid + 1
    return hi


def run_envelope(t: np.ndarray, x: np.ndarray, runs: np.ndarray, size: int
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The ``[start, end)`` runs of ``(t, x)`` in buckets of ``size`` samples (``size`` 1: the
    samples themselves), each bucket inside one run, as min/max rows in time order.

    A run's last bucket is padded by repeating the run's last sample (which changes neither its
    min nor its max), so every row is stamped at a time inside its own run.
    """
    x2 = x[:, None] if x.ndim == 1 else x
    starts, lengths = runs[:, 0], runs[:, 1] - runs[:, 0]
    if size == 1:
        idx = _indices(starts, lengths, lengths)
        return t[idx], x[idx]
    n_buckets = -(-lengths // size)  # per run
    k = x2.shape[1]
    if len(runs) == 1 and lengths[0] == n_buckets[0] * size:
        # One run of whole buckets (a per-axis signal, a chunk of one): its rows as they lie.
        a, b = int(starts[0]), int(runs[0, 1])
        v = _min_max_rows(x2[a:b].reshape(-1, size, k))
        te = np.column_stack([t[a:b:size], t[a + size // 2:b:size]]).ravel()
    else:
        idx = _indices(starts, lengths, n_buckets * size)
        v = _min_max_rows(x2[idx].reshape(-1, size, k))
        te = np.column_stack([t[idx[::size]], t[idx[size // 2::size]]]).ravel()
    out = v.reshape(-1, k)
    return te, (out[:, 0] if x.ndim == 1 else out)


def _indices(starts: np.ndarray, lengths: np.ndarray, padded: np.ndarray) -> np.ndarray:
    """Sample index of every position of the runs, each run padded to ``padded`` positions by
    repeating its last sample: position j of run r is ``starts[r] + min(j, lengths[r] - 1)``."""
    run_of = np.repeat(np.arange(len(starts)), padded)
    j = np.arange(int(padded.sum())) - np.repeat(np.cumsum(padded) - padded, padded)
    return starts[run_of] + np.minimum(j, lengths[run_of] - 1)


def _min_max_rows(xb: np.ndarray) -> np.ndarray:
    """(buckets, 2, k): each bucket's minimum and maximum per column, in the order they occur."""
    i_min = np.argmin(xb, axis=1)
    i_max = np.argmax(xb, axis=1)
    v = np.empty((len(xb), 2, xb.shape[2]), dtype=xb.dtype)
    v[:, 0] = np.take_along_axis(xb, np.minimum(i_min, i_max)[:, None, :], axis=1)[:, 0]
    v[:, 1] = np.take_along_axis(xb, np.maximum(i_min, i_max)[:, None, :], axis=1)[:, 0]
    return v
