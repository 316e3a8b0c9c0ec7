"""Static detector (method.md §1, equation M1)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from imucal.errors import ImucalError
from imucal.numerics.windows import (
    block_means,
    chunked_window_sums,
    median_inplace,
    rolling_variance,
    runs_of_true,
)
from imucal.settings import DetectSettings, Settings


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
        m = chunked_window_sums(y, w, o1 - o0, b)
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


def detect_static(acc: np.ndarray, t: np.ndarray, settings: DetectSettings = Settings().detect,
                  source: str = "session") -> Detection:
    """Mark where the sensor lies still (M1) and cut the still samples into blocks."""
    n = len(acc)
    dt = np.diff(t)
    increasing = bool(len(dt) and dt.min() > 0)
    rate = 1.0 / median_inplace(dt)
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


