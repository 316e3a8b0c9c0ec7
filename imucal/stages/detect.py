"""Static detector (method.md §1, equation M1): the statistic, the blocks at given values, and
the isolated outliers it must not trip over. Choosing the values from the data is
:mod:`imucal.stages.detect_tuning`."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from imucal.errors import ImucalError
from imucal.numerics.windows import (
    block_means,
    chunked_window_sums,
    median_inplace,
    rolling_variance,
    runs_of_true,
)
from imucal.settings import THESIS_INIT, DetectSettings, Settings

# The thesis's values (method.md §1), in seconds: its 101-sample window and 100-sample
# shortest block at 100 Hz (its initial still interval is settings.THESIS_INIT).
THESIS_WINDOW_S = 1.01
THESIS_MIN_LEN_S = 1.0
THESIS_K = 2.0


@dataclass(frozen=True)
class Candidate:
    """One setting of the detector that was tried, and what it gave."""

    window: int  # samples
    min_len: int  # samples
    k: float  # threshold multiplier on the reference level
    blocks: int
    orientations: int  # distinct still directions (15 degrees apart)
    score_mg: float | None  # cross-validated static norm error of block means; None: not scored


@dataclass(frozen=True)
class Tuning:
    """How the detector chose its values: what it tried, what it took and why."""

    tuned: tuple[str, ...]  # the settings the data chose ("window", "min_len", "k")
    reference: str  # where the reference level s2_init came from
    local_factor: float | None  # blocks end where s2 exceeds this times their own median s2
    quiet_level: float  # low quantile of s2 over the windows of the whole recording
    quiet_window: int  # the windows': the shortest tried when it was the reference
    candidates: tuple[Candidate, ...]
    chosen: int  # index into candidates
    reason: str
    hold_s: float | None  # median duration of the chosen blocks plus one window, s
    short_holds: int = 0  # still stretches too short for a block, at the shortest window tried
    min_hold_s: float | None = None  # the shortest still stretch a block comes from there, s


@dataclass(frozen=True)
class Detection:
    """Where the sensor lies still: the statistic, the threshold and the blocks found."""

    statistic: np.ndarray  # s2(t) per accelerometer sample (M1)
    threshold: float  # k * s2_init
    s2_init: float  # the reference level (the initial still interval's s2, or the quiet level)
    blocks: np.ndarray  # (B, 2) int, [start, end) accelerometer sample indices
    means: np.ndarray  # (B, 3) raw mean accelerometer vector of each block
    window: int
    min_len: int
    init: tuple[float, float] | None = THESIS_INIT  # where s2_init came from; None: quiet level
    k: float = THESIS_K
    note: str | None = None  # the initial interval was not still: what was done instead
    outliers: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # sample indices
    outlier_note: str | None = None  # the outliers named for the user
    tuning: Tuning | None = None  # how the values were chosen (None: all given)
    orientations: int | None = None  # distinct still directions of the blocks


# The initial interval must be still (method.md §1): its mean may not wander. It is cut into
# INIT_PARTS parts and the spread of their means compared with what the noise inside them allows
# (an F ratio): about 1 for a still sensor, 1.3-3.8 on the real recordings in shared/data,
# hundreds to thousands once the device turns during it.
INIT_PARTS = 5
INIT_MAX_F = 30.0

# An isolated outlier (a glitch, a bit error, an absurd 1e12) is a sample far from the mean of
# its two neighbours -- SPIKE_NOISE times the recording's typical such distance -- while the
# neighbours themselves agree: SPIKE_ISOLATION times their own steps. A smooth swing, even a
# violent one, bends over several samples and fails the second test.
SPIKE_NOISE = 50.0
SPIKE_ISOLATION = 5.0


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


def sample_rate(t: np.ndarray) -> tuple[float, bool]:
    """Median sample rate (Hz) and whether the timestamps strictly increase."""
    dt = np.diff(t)
    increasing = bool(len(dt) and dt.min() > 0)
    return 1.0 / median_inplace(dt), increasing


def thesis_window(rate: float) -> int:
    """The thesis's 1.01 s window at ``rate``, odd (a centred window), at least 3 samples."""
    return max(3, int(round(THESIS_WINDOW_S * rate)) | 1)


def thesis_min_len(rate: float) -> int:
    return max(1, int(round(THESIS_MIN_LEN_S * rate)))


def isolated_outliers(x: np.ndarray) -> np.ndarray:
    """Indices of isolated outlier samples (see SPIKE_NOISE), in O(N) per axis.

    ``e_i = x_i - (x_(i-1) + x_(i+1)) / 2`` is the distance from the neighbours' mean; its
    typical size (1.4826 x the median of |e|, on a subsample of long recordings) is the sensor
    noise. Only the few samples far beyond it have their neighbours' steps compared. The ends
    are mirrored, so the first and last samples are judged too.
    """
    x = np.asarray(x, dtype=np.float64)
    n = len(x)
    if n < 5:
        return np.zeros(0, np.int64)
    stride = max(1, n // 200_000)
    found = []
    for j in range(x.shape[1]):
        c = x[:, j]
        p = np.concatenate([c[2:0:-1], c, c[-2:-4:-1]])  # mirrored about both ends
        e = p[1:n + 1] + p[3:n + 3]
        e *= -0.5
        e += c
        np.abs(e, out=e)
        scale = 1.4826 * float(np.median(e[::stride]))
        if scale == 0.0:  # quantised: most samples equal their neighbours
            scale = float(np.mean(e))
        if scale == 0.0 or not np.isfinite(scale):
            continue
        i = np.flatnonzero(e > SPIKE_NOISE * scale)  # few: the steps only there
        q = i + 2  # index into p
        steps = np.maximum.reduce([np.abs(p[q + 1] - p[q - 1]), np.abs(p[q + 2] - p[q + 1]),
                                   np.abs(p[q - 1] - p[q - 2])]) if len(i) else np.zeros(0)
        found.append(i[e[i] > SPIKE_ISOLATION * steps])
    return np.unique(np.concatenate(found)) if found else np.zeros(0, np.int64)


def without_outliers(x: np.ndarray, outliers: np.ndarray) -> np.ndarray:
    """``x`` with each outlier replaced by the mean of its neighbours (``x`` itself if none):
    what the detector's statistic is computed on."""
    if len(outliers) == 0:
        return x
    n = len(x)
    out = np.array(x, dtype=np.float64)
    lo = np.where(outliers > 0, outliers - 1, outliers + 1)
    hi = np.where(outliers < n - 1, outliers + 1, outliers - 1)
    out[outliers] = 0.5 * (out[lo] + out[hi])
    return out


def outlier_note(outliers: np.ndarray, t: np.ndarray, acc: np.ndarray) -> str | None:
    if len(outliers) == 0:
        return None
    shown = ", ".join(f"sample {i} (t = {t[i]:.3f} s, {np.array2string(acc[i], precision=4)})"
                      for i in outliers[:5])
    more = f" and {len(outliers) - 5} more" if len(outliers) > 5 else ""
    one = len(outliers) == 1
    return (f"{len(outliers)} isolated outlier sample{'' if one else 's'} in the accelerometer, "
            f"far from both neighbours: {shown}{more}; the static detector ignored "
            f"{'it' if one else 'them'} and left {'it' if one else 'them'} out of every still "
            "block (a logger or transmission glitch?)")


def still_blocks(stat: np.ndarray, threshold: float, min_len: int, outliers: np.ndarray
                 ) -> np.ndarray:
    """Runs of ``stat < threshold`` at least ``min_len`` long; an outlier sample ends a run."""
    mask = stat < threshold
    if len(outliers):
        mask[outliers] = False
    runs = runs_of_true(mask)
    return runs[(runs[:, 1] - runs[:, 0]) >= min_len].astype(np.int64).reshape(-1, 2)


def initial_level(acc: np.ndarray, t: np.ndarray, init: tuple[float, float], statistic: str,
                  source: str, *, slide: bool = True
                  ) -> tuple[float | None, tuple[float, float] | None, str | None]:
    """The reference level ``s2_init`` (M1 over the initial still interval, thesis §3.1), the
    interval it came from and a note for the user.

    An interval whose mean wanders (:func:`wander_ratio`) is not still. With ``slide`` (an
    interval the user set, or the plain detector) the first still stretch as long takes its
    place, and a recording never still that long is an error; without it (the tuner, which
    has the quiet level of the whole recording to fall back on) ``(None, None, note)``.
    """
    t0, t1 = init
    increasing = bool(len(t) > 1 and np.all(np.diff(t) > 0))
    if increasing:  # the interval is a slice: no masks the length of the recording
        i0, i1 = np.searchsorted(t, [t[0] + t0, t[0] + t1], side="left")
        samples = acc[i0:i1]
    else:
        samples = acc[(t >= t[0] + t0) & (t < t[0] + t1)]
    if len(samples) < 10:
        if not slide:
            return None, None, None
        raise ImucalError(f"the initial still interval {t0:g}-{t1:g} s holds only {len(samples)} "
                          "samples; the session must start with the device still for a few "
                          "seconds", source=source, field="initial still period")
    note = None
    if increasing:  # (the search below slides slices along the time axis)
        f = wander_ratio(samples)
        if f > INIT_MAX_F:
            moving = (f"the accelerometer moves during the initial still interval {t0:g}-{t1:g} "
                      f"s (its mean wanders {f:.0f}x more than its noise allows)")
            if not slide:
                return None, None, moving
            samples, (t0, t1) = _first_still_interval(acc, t, t0, t1, f, source)
            note = (f"{moving}; the noise level was learned from {t0:g}-{t1:g} s instead, the "
                    "first still stretch: start recordings with the sensor lying still, or set "
                    "the interval (--init START END)")
    s2 = float(combine_variances(np.var(samples, axis=0, ddof=1), statistic))
    if not np.isfinite(s2) or s2 <= 0.0:
        if not slide:
            return None, None, None
        raise ImucalError("the accelerometer is exactly constant over the initial interval, so no "
                          "noise level can be learned from it (quantised or synthetic data?)",
                          source=source, field="initial still period")
    return s2, (float(t0), float(t1)), note


def detect_static(acc: np.ndarray, t: np.ndarray, settings: DetectSettings = Settings().detect,
                  source: str = "session") -> Detection:
    """Mark where the sensor lies still (M1) and cut the still samples into blocks, at the
    given values; a value left ``None`` is the thesis's (choosing them from the data is
    :func:`imucal.stages.detect_tuning.tune_detector`)."""
    n = len(acc)
    rate, _ = sample_rate(t)
    window = settings.window or thesis_window(rate)
    min_len = settings.min_len or thesis_min_len(rate)
    k = THESIS_K if settings.k is None else float(settings.k)
    check_window(window, n, source)
    outliers = isolated_outliers(acc)
    clean = without_outliers(acc, outliers)
    stat = rolling_statistic(clean, window, settings.statistic)
    s2_init, init, note = initial_level(clean, t, settings.init or THESIS_INIT,
                                        settings.statistic, source)
    threshold = k * s2_init
    blocks = still_blocks(stat, threshold, min_len, outliers)
    return Detection(statistic=stat, threshold=threshold, s2_init=s2_init, blocks=blocks,
                     means=block_means(acc, blocks), window=window, min_len=min_len, init=init,
                     k=k, note=note, outliers=outliers,
                     outlier_note=outlier_note(outliers, t, acc))


def check_window(window: int, n: int, source: str) -> None:
    if window < 3:
        raise ImucalError(f"detector window must be at least 3 samples, got {window}",
                          source="settings", field="window")
    if n < window:
        raise ImucalError(f"only {n} accelerometer samples, fewer than one detector window "
                          f"({window}); record longer", source=source, field="accelerometer")


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
