"""The static detector's values chosen from the recording (method.md §1).

Fixed values break on real files: initial still periods of 2 s to a minute, sensors whose
still/moving contrast needs k from 2 to 16 and more, poses held 1 s (shorter than the thesis's
window plus its shortest block). So, for every value the user left unset:

* The reference level is the initial still interval's (thesis §3.1) when that interval really
  is still (its mean does not wander, :func:`~imucal.stages.detect.wander_ratio`), else the
  quiet level of the whole recording: a low quantile of M1 over short windows.
* k is scanned over a wide grid; ``s2 < k * s2_init`` finds the still stretches, and each
  stretch ends where its own M1 leaves its own noise: ``s2 > LOCAL(w) * median s2`` over the
  stretch, ``LOCAL(101) = 2`` the thesis's k. A sensor whose poses are noisier than its
  initial rest (a hand holds them) needs a large k to find them; the local level keeps such a
  k from stretching every block into the turns, which the accelerometer barely sees (a block
  mean hardly moves: measured, k = 2 -> 32 on a synthetic session lowers the accelerometer's
  cross-validated error 0.195 -> 0.177 mg while the gravity error grows 0.045 -> 0.41 deg)
  and the gyroscope fit pays for (M5).
* Each candidate is scored by a cross-validated static norm error of block means
  (:mod:`imucal.stages.detect_score`; imu_tk keeps the lowest in-sample residual over k =
  2..10, which more, shorter blocks always lower). Candidates must keep MIN_ORIENTATIONS
  distinct directions and nine tenths of the most any candidate found, so dropping the
  awkward poses does not win either.
* The window starts at the thesis's 1.01 s and is halved while the blocks found are not
  comfortably longer than it (short holds), down to 0.25 s (MIN_WINDOW_S: shorter windows
  see a turn's slow start too late) and never below MIN_WINDOW samples (the noise); the
  shortest block keeps the thesis's ratio to the window.

M1 is computed once per window tried (:func:`~imucal.stages.detect_runs.window_pass`, a span at
a time: its values are never all kept); the thresholds are tried on its per-bin maximum (a few
samples a bin), and the chosen setting is redone at full resolution in one more pass. What was
tried and why one was taken goes in :class:`Tuning`.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from imucal.errors import ImucalError
from imucal.numerics.rows import RowRange
from imucal.settings import THESIS_INIT, DetectSettings
from imucal.stages.detect import (
    INIT_MAX_F,
    THESIS_MIN_LEN_S,
    THESIS_WINDOW_S,
    Candidate,
    Detection,
    Tuning,
    check_window,
    glitches,
    initial_level,
    isolated_outliers,
    outlier_note,
    sample_rate,
    thesis_window,
    wander_ratio,
)
from imucal.stages.detect_runs import WindowPass, still_runs, streamed_still_runs, window_pass
from imucal.stages.detect_score import MIN_ORIENTATIONS, Blocks, Prefix, Scorer
from imucal.stages.detect_stat import CleanRows, Statistic

K_GRID = tuple(2.0 ** (i / 2) for i in range(19))  # 1 ... 512, a factor sqrt(2) apart
MIN_WINDOW = 11  # samples: below, a still window's variance scatters by more than +-45 %
MIN_WINDOW_S = 0.25  # s: shorter windows see a turn's slow start too late (measured: blocks
# of 0.13 s in 0.15 s holds fit the accelerometer to 0.34 mg but the gyroscope to 3 degrees)
HALVINGS = 2  # the window goes down to a quarter of the thesis's (0.25 s) for short holds
HOLD_WINDOWS = 1.5  # a window fits the holds when the median block is this many windows long
QUIET_QUANTILE = 0.05  # the quietest 5 % of short windows tell the noise level
KEEP_ORIENTATIONS = 0.9  # of the most orientations any candidate found
TIE = 0.10  # scores within 10 % of the best are the same: cross-validation noise
BIN_SAMPLES = 16  # scan bins: about window / 16 samples each


def local_factor(window: int, statistic: str = "thesis") -> float:
    """How far M1 may rise over a still stretch's own median before the stretch ends: three
    standard deviations of a variance over ``window - 1`` degrees of freedom, squared (M1
    squares variances; imu_tk's norm of the variances does not). 2.0 at the thesis's 101
    samples, its k; measured on white noise it lies between the 99.9 % points of one axis
    alone and of three equal axes."""
    f = 1.0 + 3.0 * math.sqrt(2.0 / max(window - 1, 1))
    return f * f if statistic == "thesis" else f


def tune_detector(acc, t, settings: DetectSettings, *, acc_unit: str = "g", g_in: float = 1.0,
                  source: str = "session", rate: float | None = None) -> Detection:
    """Detect the still blocks with the values the user gave and the rest chosen from the
    data (see the module's docstring); the choice is recorded in ``Detection.tuning``.
    ``rate``: the clock's median rate where known (``Session.acc_rate``), else found here.

    ``acc`` and ``t`` are read a block of rows at a time (slices and gathers): M1 is never
    held whole, the outliers are a few indices and the scan's bins a few samples each."""
    n = len(acc)
    rate = sample_rate(t) if rate is None else rate
    windows = [settings.window] if settings.window else candidate_windows(rate, n)
    check_window(min(windows), n, source)
    outliers = isolated_outliers(acc)
    clean = CleanRows(acc, outliers)
    # An explicit k is the thesis's detector: s2 < k s2_init and nothing else.
    ks = K_GRID if settings.k is None else (float(settings.k),)
    passes: dict[int, WindowPass] = {}
    ref, init, note, reference, (quiet, wq) = _reference(clean, t, windows, passes, ks, settings,
                                                         source)
    local = settings.statistic if settings.k is None else None  # local ends, for M1 as used
    scorer = Scorer(acc_unit, g_in)
    tried: list[tuple[Candidate, Blocks]] = []
    for w in sorted(windows, reverse=True):
        if w not in passes:
            passes[w] = _pass(clean, w, settings.statistic, ks, ref)
        min_len = settings.min_len or min_len_for(w)
        found = _scan(acc, passes[w], ref, ks, min_len, outliers, local, scorer)
        tried += found
        if _fits_the_holds(found, w):
            break
    cands = [c for c, _ in tried]
    chosen, why = choose(cands)
    best = cands[chosen]

    # The chosen setting at full resolution (the scan ran on bins).
    threshold = best.k * ref
    q = local_factor(best.window, local) if local else None
    runs = streamed_still_runs(Statistic(clean, best.window, settings.statistic), threshold, q,
                               outliers, passes[best.window].still_samples(threshold))
    lengths = runs[:, 1] - runs[:, 0]
    exact = Blocks.exact(acc, runs[lengths >= best.min_len])
    blocks = exact.blocks
    cands[chosen] = scorer.candidate(best.window, best.min_len, best.k, exact, force=True)
    reason = why(cands[chosen])
    _refuse_never_still(clean, blocks, source)
    short, min_hold, short_starts = _short_holds(clean, passes, settings, threshold, local,
                                                 outliers, (best.window, runs))
    tuned = tuple(name for name, v in (("window", settings.window), ("min_len", settings.min_len),
                                       ("k", settings.k)) if v is None)
    tuning = Tuning(
        tuned=tuned, reference=reference, local_factor=q, quiet_level=quiet, quiet_window=wq,
        candidates=tuple(cands), chosen=chosen, reason=reason,
        hold_s=float((np.median(exact.counts) + best.window) / rate) if len(blocks) else None,
        short_holds=short, min_hold_s=min_hold / rate, short_hold_starts=short_starts)
    named = glitches(outliers, acc, clean, passes[best.window].at_outliers, threshold)
    return Detection(threshold=threshold, s2_init=ref, blocks=blocks, means=exact.means,
                     window=best.window, min_len=best.min_len, init=init, k=best.k, note=note,
                     outliers=outliers, outlier_note=outlier_note(named, t, acc), tuning=tuning,
                     orientations=cands[chosen].orientations, statistic_kind=settings.statistic)


def _reference(clean: CleanRows, t, windows: list[int], passes: dict[int, WindowPass],
               ks: tuple[float, ...], settings: DetectSettings, source: str
               ) -> tuple[float, tuple[float, float] | None, str | None, str, tuple[float, int]]:
    """The reference level s2_init, the interval it came from, a note for the user, where it
    came from in words, and the quiet level with its window. M1's pass goes into ``passes``:
    over the shortest window when the quiet level is the reference (short windows fit in short
    holds), else over the thesis's, which the scan needs first anyway."""
    ref, init, note = initial_level(clean, t, settings.init or THESIS_INIT, settings.statistic,
                                    source, slide=settings.init is not None)
    w = min(windows) if ref is None else max(windows)
    passes[w] = _pass(clean, w, settings.statistic, ks, ref)
    quiet = quiet_level(passes[w].sample)
    if ref is not None:
        return (ref, init, note, f"the initial still interval {init[0]:g}-{init[1]:g} s",
                (quiet, w))
    if not quiet > 0.0:
        raise ImucalError("the accelerometer is exactly constant over most of the recording, so "
                          "no noise level can be learned (quantised or synthetic data?)",
                          source=source, field="accelerometer")
    if note:
        note += ("; the noise level was learned from the quietest stretches of the recording "
                 "instead: start recordings with the sensor lying still")
    return quiet, None, note, (f"the quiet level: the lowest {QUIET_QUANTILE:.0%} of M1 over "
                               f"{w}-sample windows of the whole recording"), (quiet, w)


def _pass(clean: CleanRows, window: int, statistic: str, ks: tuple[float, ...],
          ref: float | None) -> WindowPass:
    """One window's pass over M1, counting the still samples at each threshold when the
    reference level is known."""
    thresholds = None if ref is None else np.array([k * ref for k in ks])
    return window_pass(Statistic(clean, window, statistic), max(1, window // BIN_SAMPLES),
                       clean.outliers, thresholds)


def _short_holds(clean: CleanRows, passes: dict[int, WindowPass], settings: DetectSettings,
                 threshold: float, local: str | None, outliers: np.ndarray,
                 chosen: tuple[int, np.ndarray]) -> tuple[int, int, np.ndarray]:
    """How many still stretches, seen through the shortest window tried, were too short to
    make a block there, the shortest a block can come from (``min_len`` still windows:
    ``min_len + w - 1`` samples), and where each short one starts (a sample index: the guide
    names them by time). The chosen window's runs serve when it is the shortest."""
    w = min(passes)
    shortest = settings.min_len or min_len_for(w)
    runs = chosen[1]
    if w != chosen[0]:
        runs = streamed_still_runs(Statistic(clean, w, settings.statistic), threshold,
                                   local_factor(w, local) if local else None, outliers,
                                   passes[w].still_samples(threshold))
    lengths = runs[:, 1] - runs[:, 0]
    short = (lengths >= 2) & (lengths < shortest)
    return int(np.sum(short)), shortest + w - 1, runs[short, 0].astype(np.int64)


def candidate_windows(rate: float, n: int) -> list[int]:
    """The thesis's window and its halvings down to the noise's floor, odd, at most ``n``."""
    w0 = thesis_window(rate)
    floor = max(MIN_WINDOW, int(round(MIN_WINDOW_S * rate)) | 1)
    out = [w0] + [(w0 >> j) | 1 for j in range(1, HALVINGS + 1) if (w0 >> j) | 1 >= floor]
    fit = [w for w in out if w <= n]
    return fit or [min(out)]


def min_len_for(window: int) -> int:
    """The shortest block for a window: the thesis's ratio (100 samples for 101)."""
    return max(1, int(round(window * THESIS_MIN_LEN_S / THESIS_WINDOW_S)))


def quiet_level(sample: np.ndarray, quantile: float = QUIET_QUANTILE,
                flat: float = 0.0) -> float:
    """The noise level of the quietest stretches: a low quantile of M1 over short windows, from
    every stride-th window of a long recording (:class:`WindowPass.sample`). Flat windows (M1
    at or below ``flat``: a flat, clipped or quantised axis) say nothing about the noise and
    are left out; a quantile is not moved by a few wild windows."""
    s = sample[sample > flat]
    return float(np.quantile(s, quantile)) if len(s) else 0.0


def _scan(acc, wp: WindowPass, ref: float, ks: tuple[float, ...], min_len: int,
          outliers: np.ndarray, local: str | None, scorer: Scorer
          ) -> list[tuple[Candidate, Blocks]]:
    """Every k at one window, on bins of ``window / BIN_SAMPLES`` samples: a bin is still when
    its largest M1 is, so the blocks are the full-resolution ones trimmed by less than a bin
    at each end."""
    d, window = wp.per, wp.window
    pre = Prefix(acc, d)
    q = local_factor(window, local) if local else None
    out = []
    for k in ks:
        runs = still_runs(wp.binmax, k * ref, q, outliers, per=d)
        runs = runs[(pre.count[runs[:, 1]] - pre.count[runs[:, 0]]) >= min_len]
        blk = Blocks.of(pre, runs)
        out.append((scorer.candidate(window, min_len, k, blk), blk))
    return out


def _fits_the_holds(found: list[tuple[Candidate, Blocks]], window: int) -> bool:
    """Is this window short enough for the holds? Its best-scoring eligible candidate's median
    block is at least HOLD_WINDOWS windows long (the thesis: 3 s holds, 2 s blocks, 1 s
    window). None eligible: too few poses found, and shorter windows may find more."""
    most = max((c.orientations for c, _ in found), default=0)
    eligible = [(c, b) for c, b in found if c.score_mg is not None
                and c.orientations >= max(MIN_ORIENTATIONS, KEEP_ORIENTATIONS * most)]
    if not eligible:
        return False
    _, blk = min(eligible, key=lambda x: x[0].score_mg)
    return bool(np.median(blk.counts) >= HOLD_WINDOWS * window)


def choose(cands: list[Candidate]) -> tuple[int, Callable[[Candidate], str]]:
    """The candidate to take, and how to say why (given its row redone at full resolution).

    The eligible candidates keep enough orientations; the lowest cross-validated error among
    them wins, and candidates within TIE of it are as good: of those, the longest window (the
    thesis's, when the holds allow it) and then the middle k of the plateau, a threshold with
    equally good neighbours on both sides. Where no candidate has MIN_ORIENTATIONS, no error
    can be cross-validated: the most orientations, the longest window and the middle k.
    """
    most = max(c.orientations for c in cands)
    scored = [i for i, c in enumerate(cands) if c.score_mg is not None
              and c.orientations >= max(MIN_ORIENTATIONS, KEEP_ORIENTATIONS * most)]
    pool = scored or [i for i, c in enumerate(cands) if c.orientations == most]
    if scored:
        best = min(scored, key=lambda i: cands[i].score_mg)
        pool = [i for i in scored if cands[i].score_mg <= cands[best].score_mg * (1 + TIE)]
    window = max(cands[i].window for i in pool)
    plateau = sorted((i for i in pool if cands[i].window == window), key=lambda i: cands[i].k)
    chosen = plateau[len(plateau) // 2]

    def why(c: Candidate) -> str:
        head = f"window {c.window}, k = {c.k:.3g}, {c.blocks} blocks in {c.orientations} " \
               "orientations"
        if not scored:
            return (f"{head}: no setting found the {MIN_ORIENTATIONS} distinct orientations a "
                    f"cross-validated score needs; of those with the most ({most}), the longest "
                    "window and the middle k")
        b = cands[best]
        return (f"{head}, cross-validated static norm error {c.score_mg:.3g} mg; the lowest of "
                f"the {len(scored)} settings with enough orientations was {b.score_mg:.3g} mg "
                f"(window {b.window}, k = {b.k:.3g}); of the {len(pool)} within {TIE:.0%} of "
                "it, the longest window and the middle of its plateau of k")

    return chosen, why


def _refuse_never_still(clean: CleanRows, blocks: np.ndarray, source: str) -> None:
    """Blocks whose mean wanders are slow motion, not stillness; when even the longest ones
    do, the recording has no still period at all."""
    if len(blocks) == 0:
        return
    longest = blocks[np.argsort(blocks[:, 0] - blocks[:, 1])[:5]]
    f = [wander_ratio(RowRange(clean, a, b)) for a, b in longest]
    if min(f) > INIT_MAX_F:
        raise ImucalError(f"the accelerometer is never still: even its quietest stretches drift "
                          f"(their means wander {min(f):.0f}x more than the noise allows); "
                          "record still poses, each held motionless for a few seconds",
                          source=source, field="accelerometer")
