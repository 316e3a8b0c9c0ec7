"""Static detector (method.md §1, equation M1)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import ImucalError


@dataclass(frozen=True)
class DetectSettings:
    """Settings of the static detector; sample counts default to the thesis's at its 100 Hz.

    ``window`` and ``min_len`` are in samples; ``None`` means the thesis's durations (1.01 s and
    1.0 s, i.e. 101 and 100 samples at 100 Hz) at the session's own rate. ``init`` is the
    interval (seconds from the first sample) over which the device must lie still; the thesis's
    code uses samples 50–300 at 100 Hz.
    """

    window: int | None = None
    min_len: int | None = None
    k: float = 2.0
    init: tuple[float, float] = (0.5, 3.0)
    statistic: str = "thesis"  # "thesis": M1, sum of squared variances; "imu_tk": norm of them


@dataclass(frozen=True)
class Detection:
    """Where the sensor lies still: the statistic, the threshold and the blocks found."""

    statistic: np.ndarray  # s2(t) per accelerometer sample (M1)
    threshold: float  # k * s2_init
    s2_init: float
    blocks: np.ndarray  # (B, 2) int, [start, end) accelerometer sample indices
    means: np.ndarray  # (B, 3) raw mean accelerometer vector of each block
    window: int
    min_len: int
    init: tuple[float, float] = (0.5, 3.0)  # the interval s2_init came from, s from the start
    note: str | None = None  # why it is not the one asked for


# The initial interval must be still (method.md §1): its mean may not wander. It is cut into
# INIT_PARTS parts and the spread of their means compared with what the noise inside them allows
# (an F ratio): about 1 for a still sensor, 1.3-3.8 on the real recordings in shared/data,
# hundreds to thousands once the device turns during it.
INIT_PARTS = 5
INIT_MAX_F = 30.0


def wander_ratio(x: np.ndarray, parts: int = INIT_PARTS) -> float:
    """F ratio of the part means of ``x`` (n, k) against the noise within the parts (the largest
    over the columns); 0 where a column is constant."""
    m = len(x) // parts
    if m < 2:
        return 0.0
    xp = np.asarray(x[:m * parts], dtype=np.float64).reshape(parts, m, -1)
    xp = xp - xp[0, 0]  # centred: raw counts lose no digits
    within = xp.var(axis=1, ddof=1).mean(axis=0)
    between = m * xp.mean(axis=1).var(axis=0, ddof=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.where(within > 0, between / within, np.where(between > 0, np.inf, 0.0))
    return float(f.max())


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


def rolling_statistic(x: np.ndarray, window: int, statistic: str = "thesis",
                      span: int = 1 << 17) -> np.ndarray:
    """``combine_variances(rolling_variance(x, window), statistic)`` (M1), computed ``span``
    samples at a time with every axis together, so the temporaries stay in cache and the
    recording is read once.

    Each span is centred on its own mean before the running sums (the variance does not
    depend on the shift; a local one guards even better against cancellation than the
    overall mean), so the values agree with :func:`rolling_variance`'s to rounding.
    """
    if statistic not in ("thesis", "imu_tk"):
        return combine_variances(rolling_variance(x, window), statistic)  # raises
    x = np.asarray(x, dtype=np.float64)
    n, k = x.shape
    w = int(window)
    left = w // 2
    if n <= max(left, w - 1 - left) or n <= 2 * span:
        return combine_variances(rolling_variance(x, w), statistic)
    b = max(16384, 2 * w)
    scale = w / max(w - 1, 1)
    stat = np.empty(n)
    y = None
    for o0 in range(0, n, span):
        o1 = min(n, o0 + span)
        a, c = o0 - left, o1 - left + w - 1  # the mirrored samples these outputs need
        if a >= 0 and c <= n:
            z = x[a:c]
        else:
            idx = np.arange(a, c)
            idx = np.where(idx < 0, -idx, idx)
            idx = np.where(idx > n - 1, 2 * (n - 1) - idx, idx)
            z = x[idx]
        length = c - a
        if y is None or y.shape[1] != length:
            y = np.empty((2 * k, length))
        y[:k] = z.T
        y[:k] -= y[:k].mean(axis=1, keepdims=True)
        np.multiply(y[:k], y[:k], out=y[k:])
        m = _chunked_window_sums(y, w, o1 - o0, b)
        m *= 1.0 / w
        m1, m2 = m[:k], m[k:]
        np.multiply(m1, m1, out=m1)
        v = np.subtract(m2, m1, out=m2)
        np.maximum(v, 0.0, out=v)
        v *= scale
        out = stat[o0:o1]
        np.multiply(v[0], v[0], out=out)
        for j in range(1, k):
            out += v[j] * v[j]
    return stat if statistic == "thesis" else np.sqrt(stat, out=stat)


def _median_inplace(a: np.ndarray) -> float:
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
        out[:, o0:o1] = _chunked_window_sums(z, w, o1 - o0, b)
    return out


def _chunked_window_sums(z: np.ndarray, w: int, m: int, b: int) -> np.ndarray:
    """``S[:, i] = z[:, i:i + w].sum(axis=1)`` for ``i < m``, by running sums restarted every
    ``b`` samples (see :func:`moving_sum`)."""
    k, length = z.shape
    b = max(w, min(b, length + 1))  # short signals: one chunk
    # Chunks cover at least length + 1 samples, so a window that runs past the last chunk
    # ends past the signal and is not an output.
    nch = -(-(length + 1) // b)
    Y = np.empty((k, nch * b))
    Y[:, :length] = z
    Y[:, length:] = 0.0
    Y = Y.reshape(k, nch, b)
    E = np.cumsum(Y, axis=2)
    T = E[:, :, -1].copy()  # chunk totals
    E -= Y  # exclusive running sums within each chunk
    S = Y  # no longer needed: the sums go in its place
    np.subtract(E[:, :, w:], E[:, :, :b - w], out=S[:, :, :b - w])
    np.subtract(E[:, 1:, :w], E[:, :-1, b - w:], out=S[:, :-1, b - w:])
    S[:, :-1, b - w:] += T[:, :-1, None]
    return S.reshape(k, -1)[:, :m]


def combine_variances(var: np.ndarray, statistic: str) -> np.ndarray:
    if statistic not in ("thesis", "imu_tk"):
        raise ImucalError(f"unknown static statistic {statistic!r}; expected 'thesis' or "
                          "'imu_tk'", source="settings", field="statistic")
    var = np.asarray(var, dtype=np.float64)
    if var.ndim == 1:
        out = np.sum(var * var)
    else:  # column by column: (N, 3) arrays may be column-major (see rolling_variance)
        out = var[..., 0] * var[..., 0]
        for j in range(1, var.shape[-1]):
            out += var[..., j] * var[..., j]
    if statistic == "thesis":
        return out  # M1: var_x^2 + var_y^2 + var_z^2
    return np.sqrt(out)


def runs_of_true(mask: np.ndarray) -> np.ndarray:
    """[start, end) index pairs of the runs of True in a boolean array, vectorised."""
    padded = np.concatenate(([False], mask, [False])).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    return edges.reshape(-1, 2)


def detect_static(acc: np.ndarray, t: np.ndarray, settings: DetectSettings = DetectSettings(),
                  source: str = "session") -> Detection:
    """Mark where the sensor lies still (M1) and cut the still samples into blocks."""
    n = len(acc)
    dt = np.diff(t)
    increasing = bool(len(dt) and dt.min() > 0)
    rate = 1.0 / _median_inplace(dt)
    del dt
    window = settings.window or int(round(1.01 * rate)) | 1
    min_len = settings.min_len or int(round(1.0 * rate))
    if window < 3:
        raise ImucalError(f"detector window must be at least 3 samples, got {window}",
                          source="settings", field="window")
    if n < window:
        raise ImucalError(f"only {n} accelerometer samples, fewer than one detector window "
                          f"({window}); record longer", source=source, field="accelerometer")

    stat = rolling_statistic(acc, window, settings.statistic)

    t0, t1 = settings.init
    note = None
    if increasing:  # the interval is a slice: no masks the length of the recording
        i0, i1 = np.searchsorted(t, [t[0] + t0, t[0] + t1], side="left")
        init = acc[i0:i1]
    else:
        init = acc[(t >= t[0] + t0) & (t < t[0] + t1)]
    if len(init) < 10:
        raise ImucalError(f"the initial still interval {t0:g}-{t1:g} s holds only {len(init)} "
                          "samples; the session must start with the device still for a few "
                          "seconds", source=source, field="initial still period")
    if increasing:  # (the search below slides slices along the time axis)
        f = wander_ratio(init)
        if f > INIT_MAX_F:
            init, (t0, t1) = _first_still_interval(acc, t, t0, t1, f, source)
            note = (f"the accelerometer moves during the initial still interval "
                    f"{settings.init[0]:g}-{settings.init[1]:g} s (its mean wanders {f:.0f}x "
                    f"more than its noise allows); the noise level was learned from "
                    f"{t0:g}-{t1:g} s instead, the first still stretch: start recordings with "
                    "the sensor lying still, or set the interval (--init START END)")
    init_var = np.var(init, axis=0, ddof=1)
    s2_init = float(combine_variances(init_var, settings.statistic))
    if not np.isfinite(s2_init) or s2_init <= 0.0:
        raise ImucalError("the accelerometer is exactly constant over the initial interval, so no "
                          "noise level can be learned from it (quantised or synthetic data?)",
                          source=source, field="initial still period")
    threshold = settings.k * s2_init

    runs = runs_of_true(stat < threshold)
    runs = runs[(runs[:, 1] - runs[:, 0]) >= min_len] if len(runs) else runs.reshape(0, 2)
    means = block_means(acc, runs)
    return Detection(statistic=stat, threshold=threshold, s2_init=s2_init,
                     blocks=runs.astype(np.int64), means=means, window=window, min_len=min_len,
                     init=(float(t0), float(t1)), note=note)


def _first_still_interval(acc: np.ndarray, t: np.ndarray, t0: float, t1: float, f0: float,
                          source: str) -> tuple[np.ndarray, tuple[float, float]]:
    """The first interval as long as ``t0``-``t1`` whose mean does not wander, sliding by a
    part at a time: any still stretch tells the noise level (a loop over candidate intervals,
    which stops at the first still pose, not over samples)."""
    length = t1 - t0
    starts = np.arange(t0 + length / INIT_PARTS, t[-1] - t[0] - length, length / INIT_PARTS)
    lo = np.searchsorted(t, t[0] + starts, side="left")
    hi = np.searchsorted(t, t[0] + starts + length, side="left")
    for s, i0, i1 in zip(starts, lo, hi):
        if i1 - i0 >= 10 and wander_ratio(acc[i0:i1]) <= INIT_MAX_F:
            return acc[i0:i1], (round(float(s), 3), round(float(s + length), 3))
    raise ImucalError(f"the accelerometer moves during the initial still interval {t0:g}-{t1:g} "
                      f"s (its mean wanders {f0:.0f}x more than its noise allows) and is never "
                      f"still for {length:g} s later on: record still poses, starting with the "
                      "sensor lying still", source=source, field="initial still period")


def block_means(x: np.ndarray, blocks: np.ndarray) -> np.ndarray:
    """Mean of x over each [start, end) block, in one pass (no loop over blocks)."""
    if len(blocks) == 0:
        return np.zeros((0, x.shape[1]))
    sums = segment_sums(x, blocks[:, 0], blocks[:, 1])
    return sums / np.maximum(blocks[:, 1] - blocks[:, 0], 1)[:, None]


def segment_sums(x: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Sums of the rows of ``x`` (N, k) over the ranges ``[starts[i], ends[i])``, 0 for an
    empty range.

    For sorted, non-overlapping ranges (static blocks, or the chunks of each) this is one
    ``np.add.reduceat`` pass with no temporary the size of ``x``; each sum is accumulated
    over its own range only, so it keeps full precision on long recordings (a difference of
    two cumulative sums loses the digits of the running total). Other ranges fall back to
    cumulative sums.
    """
    x = np.asarray(x)
    starts = np.asarray(starts, np.int64)
    ends = np.asarray(ends, np.int64)
    n = len(x)
    out = np.zeros((len(starts),) + x.shape[1:])
    keep = ends > starts
    s, e = starts[keep], ends[keep]
    if len(s) == 0:
        return out
    if s[0] < 0 or e[-1] > n or np.any(e[:-1] > s[1:]):
        xc = x - x[0]
        cs = np.concatenate([np.zeros((1,) + x.shape[1:]), np.cumsum(xc, axis=0)])
        out[keep] = cs[e] - cs[s] + (e - s).reshape((-1,) + (1,) * (x.ndim - 1)) * x[0]
        return out
    idx = np.empty(2 * len(s), np.int64)
    idx[0::2] = s
    idx[1::2] = e
    if idx[-1] == n:  # the last range runs to the end: reduceat's last segment does
        idx = idx[:-1]
    out[keep] = np.add.reduceat(x, idx, axis=0)[0::2]
    return out
