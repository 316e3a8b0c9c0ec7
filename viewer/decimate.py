"""Min/max envelope decimation: fewer rows for a plot, every peak kept.

A signal longer than ``max_rows`` is cut into equal buckets of consecutive samples; each bucket
becomes two rows, which hold, per column, the bucket's minimum and maximum in the order they
occur (so a rise stays a rise). The two rows are stamped with the times of the bucket's first
and middle sample: a peak is drawn at most one bucket (``len / (max_rows / 2)`` samples) away
from where it happened, and never lost. Vectorised: no loop over buckets.

:func:`detail_envelope` keeps chosen samples (the still blocks, where the method looks at the
signal) at full rate and decimates only the rest, in buckets that never straddle a kept stretch.
"""

from __future__ import annotations

import numpy as np

from imucal.numerics.windows import runs_of_true

DECIMATE_ABOVE = 200_000  # signals longer than this are drawn as an envelope
ENVELOPE_ROWS = 100_000  # rows of that envelope, at most


def for_display(t: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A per-axis signal as it is logged: itself, or its envelope past ``DECIMATE_ABOVE``."""
    return envelope(t, x, ENVELOPE_ROWS) if len(t) > DECIMATE_ABOVE else (t, x)


def magnitudes_for_display(t: np.ndarray, v: np.ndarray, still: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray]:
    """A long signal's magnitudes: full rate in the still blocks, where the calibration is
    judged to the milli-g, and a min/max envelope in between, where only the swings matter."""
    if len(t) <= DECIMATE_ABOVE:
        return t, v
    return detail_envelope(t, v, still, ENVELOPE_ROWS)


def envelope(t: np.ndarray, x: np.ndarray, max_rows: int) -> tuple[np.ndarray, np.ndarray]:
    """``(t, x)`` itself when it has at most ``max_rows`` rows, else its min/max envelope.

    ``x`` is (N,) or (N, k); the result has at most ``max_rows`` rows (and at least 2 when
    decimated) and the same number of columns.
    """
    n = len(t)
    if n <= max_rows:
        return t, x
    squeeze = x.ndim == 1
    x2 = x[:, None] if squeeze else x
    k = x2.shape[1]
    n_buckets = max(max_rows // 2, 1)
    size = -(-n // n_buckets)
    n_buckets = -(-n // size)
    pad = n_buckets * size - n
    # Pad the last bucket by repeating its last sample: it changes neither its min nor its max.
    xp = np.concatenate([x2, np.repeat(x2[-1:], pad, axis=0)]) if pad else x2
    v = _min_max_rows(xp.reshape(n_buckets, size, k))
    starts = np.arange(n_buckets) * size
    last = np.minimum(starts + size, n) - 1
    tt = np.column_stack([t[starts], t[(starts + last + 1) // 2]])
    out = v.reshape(-1, k)
    return tt.ravel(), (out[:, 0] if squeeze else out)


def detail_envelope(t: np.ndarray, x: np.ndarray, keep: np.ndarray, max_rows: int
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Samples where ``keep`` at full rate; every run of the others as a min/max envelope (at
    most about ``max_rows`` rows over all runs), merged in time order.

    Each run of dropped samples is cut into buckets of one size, its last bucket padded by
    repeating the run's last sample (which changes neither its min nor its max), so no bucket
    reaches across a kept stretch and every row is stamped at a time inside its own run.
    """
    keep = np.asarray(keep, bool)
    x2 = x[:, None] if x.ndim == 1 else x
    starts, ends = runs_of_true(~keep).T
    lengths = ends - starts
    n_drop = int(lengths.sum())
    budget = max_rows // 2 - len(starts)  # buckets left after one partial bucket per run
    if n_drop == 0 or budget <= 0 or n_drop <= max_rows:
        return t, x
    size = max(-(-n_drop // budget), 1)
    n_buckets = -(-lengths // size)  # per run
    padded = n_buckets * size
    # Gather index of the padded runs: position j of run r is sample starts[r] + min(j, L_r - 1)
    run_of = np.repeat(np.arange(len(starts)), padded)
    j = np.arange(int(padded.sum())) - np.repeat(np.cumsum(padded) - padded, padded)
    idx = starts[run_of] + np.minimum(j, lengths[run_of] - 1)
    k = x2.shape[1]
    v = _min_max_rows(x2[idx].reshape(-1, size, k))
    first = idx[::size]
    middle = idx[size // 2::size]
    te = np.column_stack([t[first], t[middle]]).ravel()
    tk = t[keep]
    # Merge the two time-sorted sets: each envelope row goes after the kept samples before it
    # (kept and dropped samples never share a time).
    at = np.searchsorted(tk, te) + np.arange(len(te))
    is_kept = np.ones(len(tk) + len(te), bool)
    is_kept[at] = False
    tt = np.empty(len(is_kept))
    tt[at], tt[is_kept] = te, tk
    out = np.empty((len(is_kept), k), dtype=x2.dtype)
    out[at], out[is_kept] = v.reshape(-1, k), x2[keep]
    return tt, (out[:, 0] if x.ndim == 1 else out)


def _min_max_rows(xb: np.ndarray) -> np.ndarray:
    """(buckets, 2, k): each bucket's minimum and maximum per column, in the order they occur."""
    i_min = np.argmin(xb, axis=1)
    i_max = np.argmax(xb, axis=1)
    v = np.empty((len(xb), 2, xb.shape[2]), dtype=xb.dtype)
    v[:, 0] = np.take_along_axis(xb, np.minimum(i_min, i_max)[:, None, :], axis=1)[:, 0]
    v[:, 1] = np.take_along_axis(xb, np.maximum(i_min, i_max)[:, None, :], axis=1)[:, 0]
    return v
