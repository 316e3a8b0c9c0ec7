"""Min/max envelope decimation: fewer rows for a plot, every peak kept.

A signal longer than ``max_rows`` is cut into equal buckets of consecutive samples; each bucket
becomes two rows, which hold, per column, the bucket's minimum and maximum in the order they
occur (so a rise stays a rise). The two rows are stamped with the times of the bucket's first
and middle sample: a peak is drawn at most one bucket (``len / (max_rows / 2)`` samples) away
from where it happened, and never lost. Vectorised: no loop over buckets.
"""

from __future__ import annotations

import numpy as np


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
    xb = xp.reshape(n_buckets, size, k)
    i_min = np.argmin(xb, axis=1)
    i_max = np.argmax(xb, axis=1)
    first = np.minimum(i_min, i_max)[:, None, :]
    second = np.maximum(i_min, i_max)[:, None, :]
    v = np.empty((n_buckets, 2, k), dtype=x2.dtype)
    v[:, 0] = np.take_along_axis(xb, first, axis=1)[:, 0]
    v[:, 1] = np.take_along_axis(xb, second, axis=1)[:, 0]
    starts = np.arange(n_buckets) * size
    last = np.minimum(starts + size, n) - 1
    tt = np.column_stack([t[starts], t[(starts + last + 1) // 2]])
    out = v.reshape(-1, k)
    return tt.ravel(), (out[:, 0] if squeeze else out)
