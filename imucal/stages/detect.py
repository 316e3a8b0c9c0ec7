"""Static detector (method.md §1, equation M1): the statistic, the blocks at given values, and
the isolated outliers it must not trip over. Choosing the values from the data is
:mod:`imucal.stages.detect_tuning`."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from imucal.errors import ImucalError
from imucal.numerics.rows import (
    ROWS,
    column_extremes,
    floats,
    pairwise_sum,
    rows_where,
    search_sorted,
    strictly_increasing,
    value_at,
)
from imucal.numerics.windows import block_means
from imucal.session import median_step
from imucal.settings import THESIS_INIT, DetectSettings, Settings
from imucal.stages.detect_runs import streamed_still_runs, values_at
from imucal.stages.detect_stat import (
    CleanRows,
    Statistic,
    combine_variances,
    rolling_statistic,
    statistic_spans,
)

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
    short_hold_starts: np.ndarray | None = None  # (short_holds,) first sample of each, int


@dataclass(frozen=True)
class Detection:
    """Where the sensor lies still: the threshold on the statistic and the blocks found.

    The statistic itself (M1 at every accelerometer sample: 173 MB at 6 hours of 1 kHz) is not
    kept: :meth:`statistic` computes it again from the accelerometer, a span at a time."""

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
    outlier_note: str | None = None  # the glitches among them named for the user (glitches())
    tuning: Tuning | None = None  # how the values were chosen (None: all given)
    orientations: int | None = None  # distinct still directions of the blocks
    statistic_kind: str = "thesis"  # M1 as the thesis squares the variances, or "imu_tk"

    def statistic(self, acc) -> np.ndarray:
        """s2(t) per accelerometer sample (M1) of the session's accelerometer ``acc``, as the
        detector saw it (its outliers replaced, its window): the same values to the bit."""
        return rolling_statistic(CleanRows(acc, self.outliers), self.window, self.statistic_kind)

    def statistic_chunks(self, acc) -> Iterator[np.ndarray]:
        """:meth:`statistic` a span at a time, in order (the same values, never whole)."""
        rows = CleanRows(acc, self.outliers)
        for _, _, s2 in statistic_spans(rows, len(rows), rows.width, self.window,
                                        self.statistic_kind):
            yield s2


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
GATHER = 1 << 15  # samples judged at once: gathered (with their neighbours), or twice as many read


def wander_ratio(x, parts: int = INIT_PARTS) -> float:
    """F ratio of the part means of ``x`` (n, k) against the noise within the parts (the largest
    over the columns); 0 where a column is constant. ``x`` is read through row slices: a span
    longer than a read (a still block hours long) a block of rows at a time."""
    m = len(x) // parts
    if m < 2:
        return 0.0
    if m * parts <= ROWS:
        xp = floats(x, 0, m * parts).reshape(parts, m, -1)
        xp = xp - xp[0, 0]  # centred: raw counts lose no digits
        within = xp.var(axis=1, ddof=1).mean(axis=0)
        means = xp.mean(axis=1)
    else:
        means, var = _part_moments(x, parts, m)
        within = var.mean(axis=0)
    between = m * means.var(axis=0, ddof=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.where(within > 0, between / within, np.where(between > 0, np.inf, 0.0))
    return float(f.max())


def _part_moments(x, parts: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """The means and variances (ddof 1) of ``parts`` consecutive parts of ``m`` rows of ``x``,
    centred on its first row, as ``var(axis=1)`` of the reshaped whole gives them: the same
    sequential sums over each part's rows, carried from one read to the next."""
    x0 = floats(x, 0, 1)[0]
    k = len(x0)
    means = np.empty((parts, k))
    var = np.empty((parts, k))
    for p in range(parts):
        for moment, out in ((1, means), (2, var)):
            acc = None
            for a in range(p * m, (p + 1) * m, ROWS):
                c = floats(x, a, min(a + ROWS, (p + 1) * m)) - x0
                if moment == 2:
                    c -= means[p]
                    np.multiply(c, c, out=c)
                acc = np.add.reduce(c if acc is None else np.vstack([acc, c]), axis=0)
            out[p] = acc / (m if moment == 1 else m - 1)
    return means, var


def sample_rate(t) -> float:
    """Median sample rate (Hz): ``1 / np.median(np.diff(t))`` to the bit, the steps read a
    block at a time (:func:`imucal.session.median_step`)."""
    return float(1.0 / median_step(t, [(0, len(t))]))


def thesis_window(rate: float) -> int:
    """The thesis's 1.01 s window at ``rate``, odd (a centred window), at least 3 samples."""
    return max(3, int(round(THESIS_WINDOW_S * rate)) | 1)


def thesis_min_len(rate: float) -> int:
    return max(1, int(round(THESIS_MIN_LEN_S * rate)))


def isolated_outliers(x) -> np.ndarray:
    """Indices of isolated outlier samples (see SPIKE_NOISE), in O(N), a block of rows at a
    time.

    ``e_i = x_i - (x_(i-1) + x_(i+1)) / 2`` is the distance from the neighbours' mean; its
    typical size (1.4826 x the median of |e| over every stride-th sample, gathered) is the
    sensor noise. Only the few samples far beyond it have their neighbours' steps compared.
    The ends are mirrored, so the first and last samples are judged too.
    """
    n = len(x)
    if n < 5:
        return np.zeros(0, np.int64)
    k = int(x.shape[1])
    sampled = np.arange(0, n, max(1, n // 200_000))
    typical = np.concatenate([_spike_sizes(x, sampled[i:i + GATHER])
                              for i in range(0, len(sampled), GATHER)])
    limit = np.empty(k)
    for j in range(k):
        s = 1.4826 * float(np.median(typical[:, j]))
        if s == 0.0:  # quantised: most samples equal their neighbours
            s = pairwise_sum(lambda a, b, j=j: _spike_sizes(x, np.arange(a, b))[:, j], n) / n
        limit[j] = SPIKE_NOISE * s if s != 0.0 and np.isfinite(s) else np.inf
    found = [np.zeros(0, np.int64)]
    for a in range(0, n, GATHER * 2):
        idx = np.arange(a, min(a + GATHER * 2, n))
        e = _spike_sizes(x, idx)
        for j in range(k):
            i = idx[e[:, j] > limit[j]]  # few: the steps only there
            if len(i):
                prev2, prev, nxt, nxt2 = (floats(x[_mirrored(i + d, n)], 0, len(i))[:, j]
                                          for d in (-2, -1, 1, 2))
                steps = np.maximum.reduce([np.abs(nxt - prev), np.abs(nxt2 - nxt),
                                           np.abs(prev - prev2)])
                found.append(i[e[i - a, j] > SPIKE_ISOLATION * steps])
    return np.unique(np.concatenate(found))


def _spike_sizes(x, idx: np.ndarray) -> np.ndarray:
    """``|e|`` (see :func:`isolated_outliers`) at the sorted sample indices ``idx``, every
    column: a slice where they are consecutive, else a gather of them and their neighbours.
    ``e = (x_prev + x_next) * -0.5 + x``, the order of operations it always had."""
    n = len(x)
    if len(idx) and idx[-1] - idx[0] == len(idx) - 1:  # consecutive: one slice, with margins
        a, b = int(idx[0]), int(idx[-1]) + 1
        lo, hi = max(a - 1, 0), min(b + 1, n)
        rows = floats(x, lo, hi)
        c = rows[a - lo:b - lo]
        prev = np.concatenate([rows[1:2], rows[:b - 1]]) if a == 0 else rows[:b - lo - 1]
        nxt = rows[a - lo + 1:]
        if b == n:
            nxt = np.concatenate([nxt, rows[-2:-1]])
    else:
        c = floats(x[idx], 0, len(idx))
        prev = floats(x[_mirrored(idx - 1, n)], 0, len(idx))
        nxt = floats(x[_mirrored(idx + 1, n)], 0, len(idx))
    e = prev + nxt
    e *= -0.5
    e += c
    return np.abs(e, out=e)


def _mirrored(k: np.ndarray, n: int) -> np.ndarray:
    """Indices reflected about both ends (-1 -> 1, n -> n - 2), as the ends are mirrored."""
    k = np.where(k < 0, -k, k)
    return np.where(k > n - 1, 2 * (n - 1) - k, k)


def glitches(outliers: np.ndarray, acc, clean: CleanRows, at_outliers: np.ndarray,
             threshold: float) -> np.ndarray:
    """The outliers that cannot be the motion itself: those in still surroundings (the
    statistic, computed without them and ``at_outliers`` there, is below the threshold) and
    those outside the range the rest of the signal spans, widened by that span (1e12 in a 2 g
    signal). A single-sample spike during a turn is as often a knock as a glitch (the Xsens
    reference recording has three); it is still left out of the statistic, but not reported as
    a fault."""
    if len(outliers) == 0:
        return outliers
    lo, hi = column_extremes(clean)
    span = hi - lo
    v = np.asarray(acc[outliers])
    absurd = np.any((v < lo - span) | (v > hi + span) | ~np.isfinite(v), axis=1)
    return outliers[(at_outliers < threshold) | absurd]


def outlier_note(outliers: np.ndarray, t, acc) -> str | None:
    """The outliers named for the user (sample, time, value), or None when there are none."""
    if len(outliers) == 0:
        return None
    first = outliers[:5]
    times, values = np.asarray(t[first]), np.asarray(acc[first])
    shown = ", ".join(f"sample {i} (t = {ti:.3f} s, {np.array2string(v, precision=4)})"
                      for i, ti, v in zip(first, times, values))
    more = f" and {len(outliers) - 5} more" if len(outliers) > 5 else ""
    one = len(outliers) == 1
    return (f"{len(outliers)} isolated outlier sample{'' if one else 's'} in the accelerometer, "
            f"far from both neighbours: {shown}{more}; the static detector ignored "
            f"{'it' if one else 'them'} and left {'it' if one else 'them'} out of every still "
            "block (a logger or transmission glitch?)")


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
    start = value_at(t, 0)
    increasing = strictly_increasing(t)
    if increasing:  # the interval is a slice: no masks the length of the recording
        i0, i1 = search_sorted(t, [start + t0, start + t1], side="left")
        samples = acc[i0:i1]
    else:
        samples = rows_where(acc, lambda a, b: (floats(t, a, b) >= start + t0)
                             & (floats(t, a, b) < start + t1))
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


def detect_static(acc, t, settings: DetectSettings = Settings().detect,
                  source: str = "session") -> Detection:
    """Mark where the sensor lies still (M1) and cut the still samples into blocks, at the
    given values; a value left ``None`` is the thesis's (choosing them from the data is
    :func:`imucal.stages.detect_tuning.tune_detector`). The blocks are runs of ``s2 <
    threshold`` at least ``min_len`` long, an outlier sample ending a run."""
    n = len(acc)
    rate = sample_rate(t)
    window = settings.window or thesis_window(rate)
    min_len = settings.min_len or thesis_min_len(rate)
    k = THESIS_K if settings.k is None else float(settings.k)
    check_window(window, n, source)
    outliers = isolated_outliers(acc)
    clean = CleanRows(acc, outliers)
    s2_init, init, note = initial_level(clean, t, settings.init or THESIS_INIT,
                                        settings.statistic, source)
    threshold = k * s2_init
    stat = Statistic(clean, window, settings.statistic)
    runs = streamed_still_runs(stat, threshold, None, outliers)
    blocks = runs[(runs[:, 1] - runs[:, 0]) >= min_len].astype(np.int64).reshape(-1, 2)
    named = glitches(outliers, acc, clean, values_at(stat, outliers), threshold)
    return Detection(threshold=threshold, s2_init=s2_init, blocks=blocks,
                     means=block_means(acc, blocks), window=window, min_len=min_len, init=init,
                     k=k, note=note, outliers=outliers, outlier_note=outlier_note(named, t, acc),
                     statistic_kind=settings.statistic)


def check_window(window: int, n: int, source: str) -> None:
    if window < 3:
        raise ImucalError(f"detector window must be at least 3 samples, got {window}",
                          source="settings", field="window")
    if n < window:
        raise ImucalError(f"only {n} accelerometer samples, fewer than one detector window "
                          f"({window}); record longer", source=source, field="accelerometer")


def _first_still_interval(acc, t, t0: float, t1: float, f0: float,
                          source: str) -> tuple[np.ndarray, tuple[float, float]]:
    """The first interval as long as ``t0``-``t1`` whose mean does not wander, sliding by a
    part at a time: any still stretch tells the noise level (a loop over candidate intervals,
    which stops at the first still pose, not over samples)."""
    length = t1 - t0
    first = value_at(t, 0)
    starts = np.arange(t0 + length / INIT_PARTS, value_at(t, -1) - first - length,
                       length / INIT_PARTS)
    lo = search_sorted(t, first + starts, side="left")
    hi = search_sorted(t, first + starts + length, side="left")
    for s, i0, i1 in zip(starts, lo, hi):
        if i1 - i0 >= 10 and wander_ratio(acc[i0:i1]) <= INIT_MAX_F:
            return acc[i0:i1], (round(float(s), 3), round(float(s + length), 3))
    raise ImucalError(f"the accelerometer moves during the initial still interval {t0:g}-{t1:g} "
                      f"s (its mean wanders {f0:.0f}x more than its noise allows) and is never "
                      f"still for {length:g} s later on: record still poses, starting with the "
                      "sensor lying still", source=source, field="initial still period")
