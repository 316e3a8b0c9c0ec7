"""Sums, means and variances over windows and index ranges of a signal, in linear time.

Plain array numerics: the static detector (method.md §1) and every stage that averages over
still blocks use them.
"""

from __future__ import annotations

import numpy as np


def rolling_variance(x: np.ndarray, window: int) -> np.ndarray:
    """Variance of each column over a centred window, O(N) via running means.

    The data are centred on their overall mean first and computed in float64, so E[x^2] - E[x]^2
    does not lose the small variance of a still sensor to cancellation (method.md §1). Windows
    at the ends are mirrored, so the first and last samples get a statistic too.
    """
    x = np.asarray(x, dtype=np.float64)
    n, k = x.shape
    var = np.empty((k, n))
    y = np.empty((2, n))
    m = np.empty((2, n))
    for j in range(k):  # one axis at a time, reusing the buffers: few large allocations
        y[0] = x[:, j]
        y[0] -= y[0].mean()
        np.multiply(y[0], y[0], out=y[1])
        moving_sum(y, window, out=m)
        m *= 1.0 / window
        np.multiply(m[0], m[0], out=m[0])
        np.subtract(m[1], m[0], out=var[j])
    # Unbiased like MATLAB's var; clip the tiny negatives that rounding can leave.
    np.maximum(var, 0.0, out=var)
    var *= window / max(window - 1, 1)
    return var.T


def median_inplace(a: np.ndarray) -> float:
    """``np.median(a)`` for a 1-D float array that may be reordered (no copy)."""
    n = len(a)
    if n == 0:
        return float("nan")
    h = n // 2
    if n % 2:
        a.partition(h)
        return float(a[h])
    a.partition([h - 1, h])
    return float(np.mean(a[h - 1:h + 1]))


def moving_sum(y: np.ndarray, window: int, chunk: int = 16384, group: int = 8,
               out: np.ndarray | None = None) -> np.ndarray:
    """Sum of each row of ``y`` (k, N) over a centred window (``window // 2`` samples before,
    the rest after), the ends mirrored about the first and last sample (scipy.ndimage's
    "mirror"), in O(N) without scipy.

    Windowed sums from one running sum, ``S[i] = C[i + w] - C[i]``, lose the small sum of a
    still window to the rounding of a large total on long recordings. Here the running sums
    restart every ``chunk`` samples, so every difference is of sums over at most one chunk,
    and a window that crosses into the next chunk adds the total of its own. The output is
    produced ``group`` chunks at a time, so the temporaries stay small.
    """
    y = np.asarray(y, dtype=np.float64)
    k, n = y.shape
    w = int(window)
    left = w // 2
    if n <= max(left, w - 1 - left):  # mirroring needs more samples than half a window
        right = w - 1 - left
        padded = np.pad(y, ((0, 0), (left, right)), mode="reflect") if n > 1 else np.repeat(
            y, w, axis=1)
        c = np.concatenate([np.zeros((k, 1)), np.cumsum(padded, axis=1)], axis=1)
        if out is None:
            return c[:, w:w + n] - c[:, :n]
        return np.subtract(c[:, w:w + n], c[:, :n], out=out)
    b = max(chunk, 2 * w)
    if out is None:
        out = np.empty((k, n))
    step = group * b
    for o0 in range(0, n, step):
        o1 = min(n, o0 + step)
        # output i sums the mirrored signal over [i - left, i - left + w)
        a, c = o0 - left, o1 - left + w - 1
        if a >= 0 and c <= n:
            z = y[:, a:c]
        else:
            idx = np.arange(a, c)
            idx = np.where(idx < 0, -idx, idx)
            idx = np.where(idx > n - 1, 2 * (n - 1) - idx, idx)
            z = y[:, idx]
        out[:, o0:o1] = chunked_window_sums(z, w, o1 - o0, b)
    return out


def chunked_window_sums(z: np.ndarray, w: int, m: int, b: int) -> np.ndarray:
    """``S[:, i] = z[:, i:i + w].sum(axis=1)`` for ``i < m``, by running sums restarted every
    ``b`` samples (see :func:`moving_sum`).

    The running sums are taken a chunk of a row at a time (numpy's cumsum along the last axis
    of a 3-d array takes twice as long), each the same sequence of additions (the compiled M1
    of :func:`variance_sumsq` repeats them in this order)."""
    k, length = z.shape
    b = max(w, min(b, length + 1))  # short signals: one chunk
    # Chunks cover at least length + 1 samples, so a window that runs past the last chunk
    # ends past the signal and is not an output.
    nch = -(-(length + 1) // b)
    Y, E = np.empty((k, nch, b)), np.empty((k, nch, b))
    flat = Y.reshape(k, -1)
    flat[:, :length] = z
    flat[:, length:] = 0.0
    need = min(m + w - (nch - 1) * b, b)  # of the last chunk: the outputs read no further
    for r in range(k):
        for c in range(nch - 1):
            np.cumsum(Y[r, c], out=E[r, c])
        np.cumsum(Y[r, -1, :need], out=E[r, -1, :need])
    E[:, -1, need:] = 0.0
    T = E[:, :, -1].copy()  # chunk totals
    E -= Y  # exclusive running sums within each chunk
    S = Y  # no longer needed: the sums go in its place
    np.subtract(E[:, :, w:], E[:, :, :b - w], out=S[:, :, :b - w])
    np.subtract(E[:, 1:, :w], E[:, :-1, b - w:], out=S[:, :-1, b - w:])
    S[:, :-1, b - w:] += T[:, :-1, None]
    return S.reshape(k, -1)[:, :m]


def runs_of_true(mask: np.ndarray) -> np.ndarray:
    """[start, end) index pairs of the runs of True in a boolean array, vectorised."""
    padded = np.concatenate(([False], mask, [False])).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    return edges.reshape(-1, 2)


def block_means(x, blocks: np.ndarray) -> np.ndarray:
    """Mean of x over each [start, end) block, in one pass (no loop over blocks), read through
    row slices (:func:`segment_sums`)."""
    if len(blocks) == 0:
        return np.zeros((0, x.shape[1]))
    sums = segment_sums(x, blocks[:, 0], blocks[:, 1])
    return sums / np.maximum(blocks[:, 1] - blocks[:, 0], 1)[:, None]


def segment_sums(x, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Sums of the rows of ``x`` (N, k) over the ranges ``[starts[i], ends[i])``, 0 for an
    empty range.

    For sorted, non-overlapping ranges (static blocks, or the chunks of each) this is
    ``np.add.reduceat`` over slices of ``x`` spanning about :data:`CHUNK_ROWS` rows (a longer
    range alone): no temporary the size of ``x``, which is read through row slices only. Each
    sum is accumulated over its own range only, as on the whole array, so it keeps full
    precision on long recordings (a difference of two cumulative sums loses the digits of the
    running total) and is the same to the bit. Other ranges fall back to cumulative sums over
    the whole array (in memory).
    """
    starts = np.asarray(starts, np.int64)
    ends = np.asarray(ends, np.int64)
    n = len(x)
    out = np.zeros((len(starts),) + tuple(x.shape[1:]))
    keep = ends > starts
    s, e = starts[keep], ends[keep]
    if len(s) == 0:
        return out
    if s[0] < 0 or e[-1] > n or np.any(e[:-1] > s[1:]):
        x = np.asarray(x)
        xc = x - x[0]
        cs = np.concatenate([np.zeros((1,) + x.shape[1:]), np.cumsum(xc, axis=0)])
        out[keep] = cs[e] - cs[s] + (e - s).reshape((-1,) + (1,) * (x.ndim - 1)) * x[0]
        return out
    where = np.flatnonzero(keep)
    i = 0
    while i < len(s):  # runs of ranges spanning about CHUNK_ROWS rows
        j = i + max(1, int(np.searchsorted(e[i:], s[i] + CHUNK_ROWS, side="right")))
        a, b = int(s[i]), int(e[j - 1])
        idx = np.empty(2 * (j - i), np.int64)
        idx[0::2] = s[i:j] - a
        idx[1::2] = e[i:j] - a
        if idx[-1] == b - a:  # the last range runs to the slice's end: reduceat's last does
            idx = idx[:-1]
        out[where[i:j]] = np.add.reduceat(np.asarray(x[a:b]), idx, axis=0)[0::2]
        i = j
    return out


def samples_within(t: np.ndarray, intervals: np.ndarray) -> np.ndarray:
    """[start, end) index pairs of the samples of a sorted time axis ``t`` inside each closed
    interval ``[t0, t1]`` of ``intervals`` (B, 2), ends included: an interval given by the
    times of its first and last sample gives back exactly those samples on the same clock."""
    intervals = np.asarray(intervals, dtype=float).reshape(-1, 2)
    lo = np.searchsorted(t, intervals[:, 0], side="left")
    hi = np.searchsorted(t, intervals[:, 1], side="right")
    return np.column_stack([lo, np.maximum(hi, lo)]).astype(np.int64)


def mask_of_runs(runs: np.ndarray, n: int) -> np.ndarray:
    """Boolean mask of length ``n``, True inside the [start, end) runs: the inverse of
    :func:`runs_of_true` (one cumulative sum, no loop over runs)."""
    runs = np.asarray(runs, np.int64).reshape(-1, 2)
    edges = np.zeros(n + 1, np.int64)
    np.add.at(edges, np.clip(runs[:, 0], 0, n), 1)
    np.add.at(edges, np.clip(runs[:, 1], 0, n), -1)
    return np.cumsum(edges[:-1]) > 0


# Rows of ``x`` centred at once by :func:`centred_segment_sums` (6 MB of float64 triples).
CHUNK_ROWS = 1 << 18


def centred_segment_sums(x: np.ndarray, starts: np.ndarray, ends: np.ndarray,
                         centre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`segment_sums` of ``x - centre`` and of ``(x - centre)**2`` (the moments of a
    block's scatter), with no temporary the size of ``x``.

    Sorted, non-overlapping ranges are taken in runs spanning about :data:`CHUNK_ROWS` rows
    (a longer range alone): each run's samples are centred and squared in one buffer. Every
    range's sum is reduced over its own samples exactly as on the whole array, so the result
    is the same to the bit. Other ranges go through the whole array at once.
    """
    starts = np.asarray(starts, np.int64)
    ends = np.asarray(ends, np.int64)
    keep = ends > starts
    s, e = starts[keep], ends[keep]
    if len(s) == 0 or s[0] < 0 or e[-1] > len(x) or np.any(e[:-1] > s[1:]):
        xc = x - centre
        s1 = segment_sums(xc, starts, ends)
        np.multiply(xc, xc, out=xc)
        return s1, segment_sums(xc, starts, ends)
    s1 = np.zeros((len(starts),) + x.shape[1:])
    s2 = np.zeros_like(s1)
    where = np.flatnonzero(keep)
    # Runs of ranges: a new run starts where the span from the run's first start would pass
    # CHUNK_ROWS (found with one pass over the ranges, not the samples).
    i = 0
    while i < len(s):
        j = i + max(1, int(np.searchsorted(e[i:], s[i] + CHUNK_ROWS, side="right")))
        a, b = int(s[i]), int(e[j - 1])
        xc = x[a:b] - centre
        s1[where[i:j]] = segment_sums(xc, s[i:j] - a, e[i:j] - a)
        np.multiply(xc, xc, out=xc)
        s2[where[i:j]] = segment_sums(xc, s[i:j] - a, e[i:j] - a)
        i = j
    return s1, s2



def variance_sumsq(zc: np.ndarray, w: int, m: int, b: int, root: bool = False) -> np.ndarray:
    """``sum_r var_r(i)^2`` (its square root with ``root``) for ``i < m``: the unbiased variance
    of each row of the centred ``zc`` (k, L) over the ``w`` samples from ``i``, by the running
    sums of :func:`chunked_window_sums` restarted every ``b`` samples, and negatives clipped to
    0, in one compiled pass with no temporaries but a row's running sums. The same values to
    the bit as those numpy operations in turn (tests/numerics/test_windows_kernel.py)."""
    from imucal.numerics.window_kernel import variance_sumsq_kernel  # numba: on first use

    k, length = zc.shape
    b = max(w, min(b, length + 1))
    return variance_sumsq_kernel(zc, int(w), int(m), int(b), 1.0 / w, w / max(w - 1, 1),
                                  bool(root))
