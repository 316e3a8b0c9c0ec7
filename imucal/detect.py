"""Static detector (method.md §1, equation M1)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import uniform_filter1d

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


def rolling_variance(x: np.ndarray, window: int) -> np.ndarray:
    """Variance of each column over a centred window, O(N) via running means.

    The data are centred on their overall mean first and computed in float64, so E[x^2] - E[x]^2
    does not lose the small variance of a still sensor to cancellation (method.md §1). Windows
    at the ends are mirrored, so the first and last samples get a statistic too.
    """
    x = np.asarray(x, dtype=np.float64)
    x = x - x.mean(axis=0)
    m1 = uniform_filter1d(x, size=window, axis=0, mode="mirror")
    m2 = uniform_filter1d(x * x, size=window, axis=0, mode="mirror")
    var = m2 - m1 * m1
    # Unbiased like MATLAB's var; clip the tiny negatives that rounding can leave.
    return np.clip(var, 0.0, None) * (window / max(window - 1, 1))


def combine_variances(var: np.ndarray, statistic: str) -> np.ndarray:
    if statistic == "thesis":
        return np.sum(var * var, axis=-1)  # M1: var_x^2 + var_y^2 + var_z^2
    if statistic == "imu_tk":
        return np.sqrt(np.sum(var * var, axis=-1))
    raise ImucalError(f"unknown static statistic {statistic!r}; expected 'thesis' or 'imu_tk'",
                      source="settings", field="statistic")


def runs_of_true(mask: np.ndarray) -> np.ndarray:
    """[start, end) index pairs of the runs of True in a boolean array, vectorised."""
    padded = np.concatenate(([False], mask, [False])).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    return edges.reshape(-1, 2)


def detect_static(acc: np.ndarray, t: np.ndarray, settings: DetectSettings = DetectSettings(),
                  source: str = "session") -> Detection:
    """Mark where the sensor lies still (M1) and cut the still samples into blocks."""
    n = len(acc)
    rate = 1.0 / float(np.median(np.diff(t)))
    window = settings.window or int(round(1.01 * rate)) | 1
    min_len = settings.min_len or int(round(1.0 * rate))
    if window < 3:
        raise ImucalError(f"detector window must be at least 3 samples, got {window}",
                          source="settings", field="window")
    if n < window:
        raise ImucalError(f"only {n} accelerometer samples, fewer than one detector window "
                          f"({window}); record longer", source=source, field="accelerometer")

    stat = combine_variances(rolling_variance(acc, window), settings.statistic)

    t0, t1 = settings.init
    sel = (t >= t[0] + t0) & (t < t[0] + t1)
    if sel.sum() < 10:
        raise ImucalError(f"the initial still interval {t0:g}-{t1:g} s holds only {sel.sum()} "
                          "samples; the session must start with the device still for a few "
                          "seconds", source=source, field="initial still period")
    init_var = np.var(acc[sel], axis=0, ddof=1)
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
                     blocks=runs.astype(np.int64), means=means, window=window, min_len=min_len)


def block_means(x: np.ndarray, blocks: np.ndarray) -> np.ndarray:
    """Mean of x over each [start, end) block, from one cumulative sum (no loop over blocks)."""
    if len(blocks) == 0:
        return np.zeros((0, x.shape[1]))
    xc = x - x[0]  # centre: keeps the cumulative sum well conditioned on long sessions
    cs = np.vstack([np.zeros((1, x.shape[1])), np.cumsum(xc, axis=0)])
    sums = cs[blocks[:, 1]] - cs[blocks[:, 0]]
    return sums / (blocks[:, 1] - blocks[:, 0])[:, None] + x[0]
