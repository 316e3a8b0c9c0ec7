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
  mean hardly moves) and the gyroscope fit pays for (M5).
* Each candidate is scored by a cross-validated static norm error (method.md §5): the
  accelerometer's block-mean fit (M2/M3 of accel.py, at a fixed small lambda) predicts every
  block from a fit without it and without the other pieces of its hold, so a hold cut in
  two cannot predict itself, and a block that swallowed a turn is predicted badly. imu_tk keeps
  the lowest in-sample residual over k = 2..10, which more, shorter blocks always lower.
  Candidates must keep MIN_ORIENTATIONS distinct directions and nine tenths of the most any
  candidate found, so dropping the awkward poses does not win either.
* The window starts at the thesis's 1.01 s and is halved while the blocks found are not
  comfortably longer than it (short holds), never below what the noise allows (MIN_WINDOW);
  the shortest block keeps the thesis's ratio to the window.

M1 is computed once per window; the thresholds are tried on its per-bin maximum (a few samples
a bin), so a scan costs a few passes over the recording, and the chosen setting is redone at
full resolution. What was tried and why one was taken goes in :class:`Tuning`.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from imucal.errors import ImucalError
from imucal.models import ACC_THETA0
from imucal.numerics.windows import runs_of_true
from imucal.settings import THESIS_INIT, DetectSettings
from imucal.stages.accel import best_fit, ellipsoid_start, jacobian, make_nominal, residuals
from imucal.stages.detect import (
    INIT_MAX_F,
    THESIS_MIN_LEN_S,
    THESIS_WINDOW_S,
    Candidate,
    Detection,
    Tuning,
    check_window,
    initial_level,
    isolated_outliers,
    outlier_note,
    rolling_statistic,
    sample_rate,
    thesis_window,
    wander_ratio,
    without_outliers,
)

K_GRID = tuple(2.0 ** (i / 2) for i in range(19))  # 1 ... 512, a factor sqrt(2) apart
MIN_WINDOW = 11  # samples: below, a still window's variance scatters by more than +-45 %
MIN_WINDOW_S = 0.25  # s: shorter windows see a turn's slow start too late (measured: blocks
# of 0.13 s in 0.15 s holds fit the accelerometer to 0.34 mg but the gyroscope to 3 degrees)
HALVINGS = 2  # the window goes down to a quarter of the thesis's (0.25 s) for short holds
HOLD_WINDOWS = 1.5  # a window fits the holds when the median block is this many windows long
QUIET_QUANTILE = 0.05  # the quietest 5 % of short windows tell the noise level
MIN_ORIENTATIONS = 12  # 9 parameters, and some to spare for the cross-validation
KEEP_ORIENTATIONS = 0.9  # of the most orientations any candidate found
TUNE_LAMBDA = 1e-4  # Tikhonov weight of the scoring fit (block means, nominal frame)
HOLD_ANGLE_DEG = 3.0  # consecutive blocks closer than this are pieces of one hold
GN_STEPS = 6  # Gauss-Newton steps of the scoring fit
TIE = 0.10  # scores within 10 % of the best are the same: cross-validation noise
BIN_SAMPLES = 16  # scan bins: about window / 16 samples each


def local_factor(window: int) -> float:
    """How far M1 may rise over a still stretch's own median before the stretch ends: three
    standard deviations of a variance over ``window - 1`` degrees of freedom, squared (M1
    squares variances). 2.0 at the thesis's 101 samples, its k; measured on white noise it
    lies between the 99.9 % points of one axis alone and of three equal axes."""
    return (1.0 + 3.0 * math.sqrt(2.0 / max(window - 1, 1))) ** 2


def tune_detector(acc: np.ndarray, t: np.ndarray, settings: DetectSettings, *,
                  acc_unit: str = "g", g_in: float = 1.0, source: str = "session") -> Detection:
    """Detect the still blocks with the values the user gave and the rest chosen from the
    data (see the module's docstring); the choice is recorded in ``Detection.tuning``."""
    n = len(acc)
    rate, _ = sample_rate(t)
    windows = [settings.window] if settings.window else candidate_windows(rate, n)
    check_window(min(windows), n, source)
    outliers = isolated_outliers(acc)
    clean = without_outliers(acc, outliers)

    stats: dict[int, np.ndarray] = {}
    wq = min(windows)
    stats[wq] = _statistic(clean, wq, settings.statistic)
    quiet = quiet_level(stats[wq])
    if not quiet > 0.0:
        raise ImucalError("the accelerometer is exactly constant over most of the recording, so "
                          "no noise level can be learned (quantised or synthetic data?)",
                          source=source, field="accelerometer")
    ref, init, note = initial_level(clean, t, settings.init or THESIS_INIT, settings.statistic,
                                    source, slide=settings.init is not None)
    if ref is None:
        ref = quiet
        reference = (f"the quiet level: the lowest {QUIET_QUANTILE:.0%} of M1 over "
                     f"{wq}-sample windows of the whole recording")
        if note:
            note += ("; the noise level was learned from the quietest stretches of the "
                     "recording instead: start recordings with the sensor lying still")
    else:
        reference = f"the initial still interval {init[0]:g}-{init[1]:g} s"
    # An explicit k is the thesis's detector: s2 < k s2_init and nothing else.
    ks = K_GRID if settings.k is None else (float(settings.k),)
    local = settings.k is None
    scorer = _Scorer(acc_unit, g_in)
    tried: list[tuple[Candidate, _Blocks]] = []
    for w in sorted(windows, reverse=True):
        if w not in stats:
            stats[w] = _statistic(clean, w, settings.statistic)
        min_len = settings.min_len or min_len_for(w)
        found = _scan(acc, stats[w], ref, ks, w, min_len, outliers, local, scorer)
        tried += found
        if _fits_the_holds(found, w):
            break
    cands = [c for c, _ in tried]
    chosen, why = choose(cands)
    best = cands[chosen]

    # The chosen setting at full resolution (the scan ran on bins).
    stat = stats[best.window]
    q = local_factor(best.window) if local else None
    runs = still_runs(stat, best.k * ref, q, outliers)
    lengths = runs[:, 1] - runs[:, 0]
    exact = _Blocks.of(_Prefix(acc, 1), runs[lengths >= best.min_len])
    blocks = exact.blocks
    cands[chosen] = scorer.candidate(best.window, best.min_len, best.k, exact, force=True)
    reason = why(cands[chosen])
    _refuse_never_still(clean, blocks, source)
    short, min_hold = _short_holds(stats, best.k * ref, local, outliers, settings.min_len)
    tuned = tuple(name for name, v in (("window", settings.window), ("min_len", settings.min_len),
                                       ("k", settings.k)) if v is None)
    tuning = Tuning(
        tuned=tuned, reference=reference, local_factor=q, quiet_level=quiet, quiet_window=wq,
        candidates=tuple(cands), chosen=chosen, reason=reason,
        hold_s=float((np.median(exact.counts) + best.window) / rate) if len(blocks) else None,
        short_holds=short, min_hold_s=min_hold / rate)
    return Detection(statistic=stat, threshold=best.k * ref, s2_init=ref, blocks=blocks,
                     means=exact.means, window=best.window, min_len=best.min_len, init=init,
                     k=best.k, note=note, outliers=outliers,
                     outlier_note=outlier_note(outliers, t, acc), tuning=tuning,
                     orientations=cands[chosen].orientations)


def _statistic(x: np.ndarray, window: int, statistic: str) -> np.ndarray:
    """M1; a variance too large for floating point is infinite: not still, and said quietly."""
    with np.errstate(over="ignore", invalid="ignore"):
        return rolling_statistic(x, window, statistic)


def _short_holds(stats: dict[int, np.ndarray], threshold: float, local: bool,
                 outliers: np.ndarray, min_len: int | None) -> tuple[int, int]:
    """How many still stretches, seen through the shortest window tried, were too short to
    make a block there, and the shortest a block can come from (``min_len`` still windows:
    ``min_len + w - 1`` samples)."""
    w = min(stats)
    shortest = min_len or min_len_for(w)
    runs = still_runs(stats[w], threshold, local_factor(w) if local else None, outliers)
    lengths = runs[:, 1] - runs[:, 0]
    return int(np.sum((lengths >= 2) & (lengths < shortest))), shortest + w - 1


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


def quiet_level(stat: np.ndarray) -> float:
    """The noise level of the quietest stretches: a low quantile of M1 over short windows.
    Exact zeros (a flat, clipped or quantised axis) say nothing about the noise and are
    left out; a quantile is not moved by a few wild windows."""
    stride = max(1, len(stat) // 500_000)  # a long recording: every stride-th window
    s = stat[::stride]
    s = s[s > 0]
    return float(np.quantile(s, QUIET_QUANTILE)) if len(s) else 0.0


def still_runs(values: np.ndarray, threshold: float, local: float | None,
               outliers: np.ndarray, per: int = 1) -> np.ndarray:
    """[start, end) runs (in units of ``per`` samples) where ``values < threshold`` and, with
    ``local``, where each such stretch's values stay under ``local`` times their median.
    Outlier samples end a run."""
    mask = values < threshold
    if len(outliers):
        mask[outliers // per] = False
    runs = runs_of_true(mask)
    if local is None or len(runs) == 0:
        return runs
    lengths = runs[:, 1] - runs[:, 0]
    label = np.repeat(np.arange(len(runs)), lengths)
    idx = np.arange(int(lengths.sum())) + np.repeat(runs[:, 0] - np.cumsum(lengths) + lengths,
                                                    lengths)
    v = values[idx]
    order = np.lexsort((v, label))  # by stretch, then by value: each stretch's median
    first = np.cumsum(lengths) - lengths
    median = v[order[first + (lengths - 1) // 2]]
    mask[idx] = v < local * median[label]
    return runs_of_true(mask)


class _Prefix:
    """Running sums of a signal over bins of ``d`` samples, centred on the first sample (raw
    counts lose no digits): the sum over any run of bins in O(1)."""

    def __init__(self, x: np.ndarray, d: int):
        x = np.asarray(x, dtype=np.float64)
        n = len(x)
        self.d, self.origin = d, x[0].copy()
        edges = np.arange(0, n, d)
        sums = np.add.reduceat(x - self.origin, edges, axis=0)
        self.s1 = np.concatenate([np.zeros((1, x.shape[1])), np.cumsum(sums, axis=0)])
        self.count = np.minimum(np.arange(len(edges) + 1) * d, n)


class _Blocks:
    """Blocks ([start, end) sample indices), their lengths and raw mean vectors."""

    def __init__(self, blocks: np.ndarray, counts: np.ndarray, means: np.ndarray):
        self.blocks, self.counts, self.means = blocks, counts, means

    @classmethod
    def of(cls, pre: _Prefix, runs: np.ndarray) -> _Blocks:
        """The blocks of ``runs`` in bins of ``pre``."""
        a, b = runs[:, 0], runs[:, 1]
        counts = (pre.count[b] - pre.count[a]).astype(np.int64)
        blocks = np.column_stack([pre.count[a], pre.count[b]]).astype(np.int64).reshape(-1, 2)
        means = (pre.s1[b] - pre.s1[a]) / np.maximum(counts, 1)[:, None] + pre.origin
        return cls(blocks, counts, means.reshape(-1, 3))


def _scan(acc: np.ndarray, stat: np.ndarray, ref: float, ks: tuple[float, ...], window: int,
          min_len: int, outliers: np.ndarray, local: bool, scorer: _Scorer
          ) -> list[tuple[Candidate, _Blocks]]:
    """Every k at one window, on bins of ``window / BIN_SAMPLES`` samples: a bin is still when
    its largest M1 is, so the blocks are the full-resolution ones trimmed by less than a bin
    at each end."""
    n = len(acc)
    d = max(1, window // BIN_SAMPLES)
    nb = -(-n // d)
    padded = np.concatenate([stat, np.full(nb * d - n, np.inf)]) if nb * d > n else stat
    binmax = padded.reshape(nb, d).max(axis=1)
    pre = _Prefix(acc, d)
    q = local_factor(window) if local else None
    out = []
    for k in ks:
        runs = still_runs(binmax, k * ref, q, outliers, per=d)
        runs = runs[(pre.count[runs[:, 1]] - pre.count[runs[:, 0]]) >= min_len]
        blk = _Blocks.of(pre, runs)
        out.append((scorer.candidate(window, min_len, k, blk), blk))
    return out


def _fits_the_holds(found: list[tuple[Candidate, _Blocks]], window: int) -> bool:
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


class _Scorer:
    """Orientations and cross-validated score of a set of blocks, cached by the blocks."""

    def __init__(self, acc_unit: str, g_in: float):
        self.acc_unit, self.g_in = acc_unit, g_in
        self.cache: dict[bytes, tuple[int, float | None]] = {}

    def candidate(self, window: int, min_len: int, k: float, blk: _Blocks, force: bool = False
                  ) -> Candidate:
        """The candidate's row; scored when it has MIN_ORIENTATIONS (or ``force``)."""
        key = blk.blocks.tobytes() + bytes([force])
        if key not in self.cache:
            self.cache[key] = self._score(blk, force)
        orient, score = self.cache[key]
        return Candidate(window, min_len, float(k), len(blk.blocks), orient, score)

    def _score(self, blk: _Blocks, force: bool) -> tuple[int, float | None]:
        p = nominal_means(blk.means, self.acc_unit, self.g_in)
        if p is None:
            return min(len(blk.means), 1), None
        orient = count_directions(p)
        if orient < 2 or not (force or orient >= MIN_ORIENTATIONS):
            return orient, None
        return orient, loo_norm_error_mg(p, blk.counts / blk.counts.sum(), same_hold(p))


def nominal_means(means: np.ndarray, acc_unit: str, g_in: float) -> np.ndarray | None:
    """Block means in the accelerometer's nominal frame (accel.make_nominal: about its zero,
    |g| about 1); ``None`` where raw counts leave the zero unknown."""
    if len(means) < 4 and acc_unit == "counts":
        return None
    try:
        p = make_nominal(means, acc_unit, g_in).to_nominal(means)
    except ImucalError:
        return None
    if not np.all(np.isfinite(p)) or np.any(np.linalg.norm(p, axis=1) == 0):
        return None
    return p


def count_orientations(means: np.ndarray, acc_unit: str, g_in: float) -> int:
    """Distinct still directions (15 degrees apart) of block means, about the accelerometer's
    nominal zero (the sphere fit's centre for raw counts)."""
    p = nominal_means(means, acc_unit, g_in)
    return min(len(means), 1) if p is None else count_directions(p)


def count_directions(p: np.ndarray, min_angle_deg: float = 15.0) -> int:
    """:func:`imucal.numerics.directions.distinct_orientations`'s greedy count, on one matrix of
    cosines (it runs on every candidate)."""
    u = p / np.linalg.norm(p, axis=1, keepdims=True)
    cos = u @ u.T
    limit = np.cos(np.radians(min_angle_deg))
    kept = [0]
    for i in range(1, len(u)):
        if cos[i, kept].max() < limit:
            kept.append(i)
    return len(kept)


def same_hold(p: np.ndarray) -> np.ndarray:
    """Per block: does it continue the hold of the block before (its direction within
    HOLD_ANGLE_DEG)? Pieces of one cut hold, not a new pose."""
    u = p / np.linalg.norm(p, axis=1, keepdims=True)
    return np.r_[False, np.einsum("ij,ij->i", u[1:], u[:-1]) > np.cos(np.radians(HOLD_ANGLE_DEG))]


def loo_norm_error_mg(p: np.ndarray, w: np.ndarray, hold: np.ndarray,
                      lam: float = TUNE_LAMBDA) -> float | None:
    """Cross-validated static norm error (method.md §5) of block means ``p`` (nominal frame,
    |g| = 1), in mg: RMS over blocks, with weights ``w`` (their share of the samples), of
    ``1 - |T K (p_b - b)|`` predicted by the M3 fit without block b and the other pieces of
    its hold (``hold``: :func:`same_hold`), so a cut hold cannot predict itself.

    The M3 fit on all blocks is Gauss-Newton from accel.py's closed-form ellipsoid start (LM,
    accel.best_fit, where that does not settle); each left-out fit is one Gauss-Newton step
    from it (``theta_-G = theta + H_-G^-1 J_G' r_G``), exact for a linear model and close for
    this nearly linear one.
    """
    theta = _fit_block_means(p, lam)
    if theta is None:
        return None
    with np.errstate(all="ignore"):
        r = residuals(theta, p)
        J = jacobian(theta, p)
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(J))):
        return None
    first = np.flatnonzero(~hold)
    group = np.cumsum(~hold) - 1
    H = J.T @ J + lam * np.eye(J.shape[1])
    JJ = np.add.reduceat(J[:, :, None] * J[:, None, :], first, axis=0)
    Jr = np.add.reduceat(J * r[:, None], first, axis=0)
    try:
        step = np.linalg.solve(H[None] - JJ, Jr[..., None])[..., 0]
    except np.linalg.LinAlgError:
        return None
    r_cv = r + np.einsum("ij,ij->i", J, step[group])
    err = float(np.sqrt(np.sum(w * r_cv * r_cv))) * 1e3
    return err if np.isfinite(err) else None


def _fit_block_means(p: np.ndarray, lam: float) -> np.ndarray | None:
    """M3 on block means with Tikhonov ``lam``: a few Gauss-Newton steps from the ellipsoid
    start (the problem is nearly linear there); LM (accel.best_fit) if they do not settle."""
    theta = ellipsoid_start(p)
    if theta is not None and np.all(theta[3:6] > 0):
        eye = lam * np.eye(9)
        with np.errstate(all="ignore"):
            for _ in range(GN_STEPS):
                r = residuals(theta, p)
                J = jacobian(theta, p)
                g = J.T @ r + lam * (theta - ACC_THETA0)
                try:
                    step = np.linalg.solve(J.T @ J + eye, g)
                except np.linalg.LinAlgError:
                    break
                theta = theta - step
                if not np.all(np.isfinite(theta)):
                    break
                if np.max(np.abs(step)) < 1e-12:
                    return theta
    start = theta if theta is not None and np.all(np.isfinite(theta)) else ACC_THETA0.copy()
    try:
        report, _ = best_fit(p, lam, {"start": start})
    except ImucalError:
        return None
    return report.theta


def _refuse_never_still(clean: np.ndarray, blocks: np.ndarray, source: str) -> None:
    """Blocks whose mean wanders are slow motion, not stillness; when even the longest ones
    do, the recording has no still period at all."""
    if len(blocks) == 0:
        return
    longest = blocks[np.argsort(blocks[:, 0] - blocks[:, 1])[:5]]
    f = [wander_ratio(clean[a:b]) for a, b in longest]
    if min(f) > INIT_MAX_F:
        raise ImucalError(f"the accelerometer is never still: even its quietest stretches drift "
                          f"(their means wander {min(f):.0f}x more than the noise allows); "
                          "record still poses, each held motionless for a few seconds",
                          source=source, field="accelerometer")
