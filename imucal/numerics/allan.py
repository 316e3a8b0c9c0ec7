"""Overlapping Allan variance at octave lags, streamed in bounded memory, and its noise fit.

The estimator (IEEE Std 952-1997 Annex C; Riley, NIST SP 1065 §5.2.4) on a signal ``x`` of
``n`` samples at period ``dt``, with the running sum ``S_j = sum_{i<j} x_i``:

    avar(m) = sum_k (S_{k+2m} - 2 S_{k+m} + S_k)^2 / (2 m^2 K)      tau = m dt

over the ``K`` start points ``k`` whose clusters fit in the signal. Fully overlapping uses every
``k``; here lag ``m`` uses every ``stride(m) = max(1, m // overlap)``-th ``k`` (``overlap=None``:
every ``k``). Neighbouring start points of a long cluster share all but ``stride`` of its
samples, so the strided sum carries the same information to within a fraction of a percent
(tested against the full estimator), and it needs the running sum only at multiples of the
stride: ``2 overlap + 1`` values per lag. That is what bounds the memory of a stream: the
accumulator keeps, per octave lag, the last ``2 m / stride <= 2 overlap`` sums (a few KB in all),
whatever the length of the signal; a chunk of samples at a time is all that is ever in memory.

The fit (IEEE 952 Annex C, the sum of independent noise terms) is linear in its coefficients:

    avar(tau) = N^2 / tau  +  c  +  K^2 tau / 3

``N`` is the line of slope -1/2 in log-log evaluated at tau = 1 s, ``K`` the line of slope +1/2
at tau = 3 s; the flat minimum of the deviation divided by 0.664 is the bias instability.
Nothing here knows what the signal measures.

Why not allantools (PyPI, maintained, 2024.6, LGPL-3): its ``oadev`` takes the whole signal as
one in-memory array; hours at 1 kHz must stream, which needs the running-sum form above. Its
textbook result is what the tests compare against (written out there, not imported).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

OVERLAP = 64  # start points per lag length: stride = m // OVERLAP (see the module docstring)
MAX_OCTAVE = 48  # lags 1 .. 2^48 samples: more than any recording holds
BIAS_INSTABILITY_FACTOR = 0.664  # sigma_min = sqrt(2 ln 2 / pi) B (IEEE 952 Table C.1)
# The octave estimates of one record share samples, so they are correlated and the fit's
# least-squares standard errors are too small: on synthetic white noise + random walk (10 seeds,
# crossover 1-69 s, one hour) the spread of the recovered K was 1.8-2.1 times the formula's.
CORRELATION_FACTOR = 2.0


@dataclass(frozen=True)
class AllanCurve:
    """Allan variance of ``k`` columns at octave lags (in samples)."""

    lags: np.ndarray  # (L,) int, cluster length m in samples
    avar: np.ndarray  # (L, k)
    terms: np.ndarray  # (L,) int, start points summed
    stride: np.ndarray  # (L,) int, spacing of the start points
    n: int  # samples the curve was computed from

    @property
    def adev(self) -> np.ndarray:
        return np.sqrt(self.avar)

    def edf(self) -> np.ndarray:
        """Equivalent degrees of freedom of each lag's estimate (white noise, Riley SP 1065
        eq. 41 simplified): about 3/2 of the independent clusters the terms span, never more
        than the terms themselves, at least 1."""
        span = self.terms * self.stride
        return np.maximum(1.0, np.minimum(self.terms, 1.5 * span / self.lags))


class AllanAccumulator:
    """Overlapping Allan variance of a signal fed a chunk at a time (``update``)."""

    def __init__(self, width: int, *, overlap: int | None = OVERLAP,
                 max_octave: int = MAX_OCTAVE) -> None:
        self.width = int(width)
        self.overlap = overlap
        self.lags = 2 ** np.arange(max_octave + 1, dtype=np.int64)
        if overlap is None:
            self.strides = np.ones_like(self.lags)
        else:
            self.strides = np.maximum(1, self.lags // int(overlap))
        self.n = 0
        self.run = 0  # samples since the last restart (the current stretch)
        self.longest = 0  # the longest stretch: what the longest cluster must fit in
        self.centre: np.ndarray | None = None
        self.total = np.zeros(self.width)  # S_n: sum of the centred samples so far
        # Per lag: the running sums at the last 2 m / stride multiples of the stride.
        self.tails = [np.zeros((1, self.width)) for _ in self.lags]  # S_0 = 0
        self.sums = np.zeros((len(self.lags), self.width))
        self.terms = np.zeros(len(self.lags), dtype=np.int64)

    def update(self, x: np.ndarray) -> None:
        x = np.asarray(x, dtype=np.float64).reshape(-1, self.width)
        if len(x) == 0:
            return
        if self.centre is None:
            # Centring keeps the running sums small: their differences lose no digits.
            self.centre = x.mean(axis=0)
        sums = np.cumsum(x - self.centre, axis=0)
        sums += self.total
        pos0 = self.run  # the sums above are S at positions pos0 + 1 .. pos0 + len(x)
        for j, (m, s) in enumerate(zip(self.lags, self.strides)):
            first = (pos0 // s + 1) * s  # first multiple of the stride after pos0
            if first > pos0 + len(x):
                continue  # nothing new at this lag's resolution
            new = sums[first - pos0 - 1::s]
            arr = np.concatenate([self.tails[j], new]) if len(new) else self.tails[j]
            r = int(m // s)
            if len(arr) > 2 * r:
                d = arr[2 * r:] - 2.0 * arr[r:len(arr) - r] + arr[:len(arr) - 2 * r]
                self.sums[j] += np.einsum("ij,ij->j", d, d)
                self.terms[j] += len(d)
                arr = arr[len(arr) - 2 * r:]
            self.tails[j] = arr.copy() if arr.base is not None else arr
        self.total = sums[-1].copy()
        self.n += len(x)
        self.run += len(x)
        self.longest = max(self.longest, self.run)

    def restart(self) -> None:
        """A gap: the samples fed next are a new stretch, and no cluster spans the gap. The
        sums and terms go on: the variance is pooled over the stretches, as
        :func:`pooled_allan_variance` pools it over still blocks."""
        self.tails = [np.zeros((1, self.width)) for _ in self.lags]
        self.total = np.zeros(self.width)
        self.run = 0

    def curve(self, min_clusters: float = 3.0) -> AllanCurve:
        """The lags with terms whose clusters fit ``min_clusters`` times in the signal."""
        keep = (self.terms > 0) & (self.lags * min_clusters <= self.longest)
        lags = self.lags[keep]
        avar = self.sums[keep] / (2.0 * lags[:, None].astype(float) ** 2
                                  * self.terms[keep][:, None])
        return AllanCurve(lags=lags, avar=avar, terms=self.terms[keep],
                          stride=self.strides[keep], n=self.n)


def allan_variance(x: np.ndarray, *, overlap: int | None = None,
                   chunk: int = 1 << 16) -> AllanCurve:
    """Overlapping Allan variance of an in-memory (n, k) signal at octave lags."""
    x = np.asarray(x, dtype=np.float64)
    x2 = x.reshape(len(x), -1)
    acc = AllanAccumulator(x2.shape[1], overlap=overlap,
                           max_octave=max(0, int(np.log2(max(len(x2), 1)))))
    for lo in range(0, len(x2), chunk):
        acc.update(x2[lo:lo + chunk])
    return acc.curve()


Rows = Callable[[int, int], np.ndarray]  # rows(a, b): the (b - a, k) rows [a, b) of a signal
RUN_ROWS = 1 << 16  # rows asked of a row getter at once: the still rows of one such cell


def pooled_allan_variance(x: np.ndarray | Rows, starts: np.ndarray, ends: np.ndarray,
                          min_clusters: float = 3.0, chunk: int = 1 << 16, *,
                          width: int = 3) -> AllanCurve:
    """Overlapping Allan variance pooled over the runs ``[starts[i], ends[i])`` of ``x``
    (n, k), or of the rows a getter ``x(a, b)`` gives (``width`` columns): every cluster lies
    inside one run, every start point counts once (fully overlapping). Lags go up to the
    longest run / ``min_clusters``.

    The runs are packed end to end into one running sum ``S`` (each run centred on its mean: no
    digits lost, and a constant within a run leaves its second differences unchanged); per lag,
    a slice of ``chunk`` start points at a time, the points whose clusters leave their run set
    to zero. ``S`` is streamed: the rows are read a cell of ``RUN_ROWS`` rows at a time (the
    still rows in it; a run across cells is put together from them), and only the window of
    ``S`` a pending slice still needs is kept (``chunk`` + twice the lag + a read: bounded by
    the longest run, not by the samples of all runs). The sums are the packed whole's to the
    bit: the running sum carries on from its last value, each lag's slices are the same, each
    summed in order (as ``einsum`` sums them) and added in the same order.
    """
    if callable(x):
        k = int(width)

        def rows(a: int, b: int) -> np.ndarray:
            # A fresh C-ordered array: the centring's mean reduces over the layout a packed
            # copy of the runs had.
            return np.ascontiguousarray(x(a, b), dtype=np.float64).reshape(b - a, k)
        whole = None
    else:
        arr = np.asarray(x, dtype=np.float64)
        arr = arr.reshape(len(arr), -1)
        k = arr.shape[1]

        def rows(a: int, b: int) -> np.ndarray:
            return arr[a:b]
        whole = rows  # a run across cells is a slice of the array, in its own layout
    starts = np.asarray(starts, dtype=np.int64)
    ends = np.asarray(ends, dtype=np.int64)
    ok = ends > starts
    starts, ends = starts[ok], ends[ok]
    lengths = ends - starts
    empty = np.zeros(0, np.int64)
    if len(lengths) == 0:
        return AllanCurve(empty, np.zeros((0, k)), empty, empty, 0)
    n = int(lengths.sum())
    run_start = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    longest = int(lengths.max())
    lags = []
    m = 1
    while m * min_clusters <= longest:
        lags.append(m)
        m *= 2
    acc = _PooledSums(lags, n, run_start, run_start + lengths, k, chunk)
    for cen in _centred_runs(rows, starts, ends, k, whole):
        acc.feed(cen)
    keep = [j for j, c in enumerate(acc.count) if c]
    lags_a = np.asarray([lags[j] for j in keep], dtype=np.int64)
    avar = [acc.total[j] / (2.0 * lags[j] * lags[j] * acc.count[j]) for j in keep]
    return AllanCurve(lags=lags_a, avar=np.asarray(avar).reshape(-1, k),
                      terms=np.asarray([acc.count[j] for j in keep], dtype=np.int64),
                      stride=np.ones_like(lags_a), n=n)


def _centred_runs(rows: Rows, starts: np.ndarray, ends: np.ndarray, k: int,
                  whole: Rows | None) -> Iterator[np.ndarray]:
    """The runs that end in each cell of ``RUN_ROWS`` rows, each centred on its mean, end to
    end (one array per cell where one ends). A cell's still rows are one read (a getter that
    computes whole cells, as ``Calibration.rows`` does, computes each once); a run across
    cells is put together from its reads, or is ``whole(a, b)`` when that is given."""
    pending: list[np.ndarray] = []  # the rows read so far of run i, begun in an earlier cell
    i, nr, pos = 0, len(starts), int(starts[0]) if len(starts) else 0
    while i < nr:
        c1 = (pos // RUN_ROWS + 1) * RUN_ROWS
        j = i + int(np.searchsorted(starts[i:], c1, side="left"))  # runs i .. j-1 meet it
        a, b = pos, min(c1, int(ends[j - 1]))
        xs = rows(a, b)
        parts, first = [], i
        if pos > starts[i]:  # run i began in an earlier cell
            if ends[i] > c1:  # and goes on past this one
                pending.append(xs)
                pos = c1
                continue
            seg = whole(int(starts[i]), int(ends[i])) if whole else np.concatenate(
                [*pending, xs[:ends[i] - a]])
            parts.append(seg - seg.mean(axis=0))
            pending, first = [], i + 1
        done = j if ends[j - 1] <= c1 else j - 1  # runs first .. done-1 end in this cell
        if first < done:
            parts.append(_centred(xs, starts[first:done] - a, ends[first:done] - a))
        if done < j:  # run `done` goes on into the next cell
            pending = [xs[starts[done] - a:]]
            i, pos = done, c1
        else:
            i = j
            pos = int(starts[j]) if j < nr else pos
        if parts:
            yield np.concatenate(parts) if len(parts) > 1 else parts[0]


def _centred(xs: np.ndarray, s: np.ndarray, e: np.ndarray) -> np.ndarray:
    """The rows ``[s[r], e[r])`` of ``xs``, each run less its mean, end to end. A C-ordered
    run's mean is its sum in order over its rows (as ``mean(axis=0)`` sums them) over its
    length, compiled (``allan_kernels.centred_runs``); other layouts take ``mean`` itself."""
    out = np.empty((int(np.sum(e - s)), xs.shape[1]))
    if xs.flags.c_contiguous and xs.dtype == np.float64:
        _kernels().centred_runs(xs, s.astype(np.int64), e.astype(np.int64), out)
        return out
    p = 0
    for a, b in zip(s.tolist(), e.tolist()):
        seg = xs[a:b]
        np.subtract(seg, seg.mean(axis=0), out=out[p:p + b - a])
        p += b - a
    return out


class _PooledSums:
    """The per-lag sums of squared second differences of the packed running sum ``S``, fed
    the centred samples in order; holds the window of ``S`` the pending slices need."""

    def __init__(self, lags: list[int], n: int, run_start: np.ndarray, run_end: np.ndarray,
                 k: int, chunk: int) -> None:
        self.lags, self.n, self.chunk = lags, n, chunk
        self.run_start, self.run_end = run_start, run_end
        # S[w0 : w0 + size - off] lies in buf[off:size]: the running sums are written in
        # place and the buffer moved up only when full (no copy of the window per feed).
        self.buf = np.zeros((1 << 17, k))  # S_0 = 0
        self.off, self.size, self.w0 = 0, 1, 0
        self.next = [0] * len(lags)  # per lag, the first start point not yet summed
        self.total = [np.zeros(k) for _ in lags]
        self.count = [0] * len(lags)

    @property
    def win(self) -> np.ndarray:
        return self.buf[self.off:self.size]

    def feed(self, cen: np.ndarray) -> None:
        n_new = len(cen)
        if self.size + n_new > len(self.buf):  # move the window up, or make room for it
            held = self.size - self.off
            buf = self.buf if held + n_new <= len(self.buf) else np.empty(
                (2 * (held + n_new), self.buf.shape[1]))
            buf[:held] = self.buf[self.off:self.size]
            self.buf, self.off, self.size = buf, 0, held
        if self.w0 + self.size - self.off > 1:  # carry on from the last S: S_{p+1} = S_p + c_0,
            cen[0] += self.buf[self.size - 1]  # and on: the sequential additions of one cumsum
        np.cumsum(cen, axis=0, out=self.buf[self.size:self.size + n_new])
        self.size += n_new
        have = self.w0 + self.size - self.off  # S_0 .. S_{have - 1} known
        for j, m in enumerate(self.lags):
            last = self.n - 2 * m + 1  # start points 0 .. last - 1
            while self.next[j] < last:
                lo = self.next[j]
                hi = min(lo + self.chunk, last)
                if hi + 2 * m > have:
                    break
                self._slice(j, m, lo, hi)
                self.next[j] = hi
        pending = [lo for lo, m in zip(self.next, self.lags) if lo < self.n - 2 * m + 1]
        keep = min(pending) if pending else have - 1
        self.off += keep - self.w0
        self.w0 = keep

    def _slice(self, j: int, m: int, lo: int, hi: int) -> None:
        """Start points ``[lo, hi)`` at lag ``m``: ``S_{i+2m} - 2 S_{i+m} + S_i``, zero where
        the cluster leaves its run (the last ``2m - 1`` points of each), summed in order.

        Only the points kept are computed and summed, per column in order from +0 (compiled,
        ``allan_kernels.kept_sum``): the same sum to the bit as ``einsum`` over the whole slice
        with the others set to zero (a zero adds +0 to a sum of squares: tested)."""
        S, o = self.win, self.w0
        # The runs meeting [lo, hi) and the points of each whose cluster stays in it.
        r0 = int(np.searchsorted(self.run_end, lo, side="right"))
        r1 = int(np.searchsorted(self.run_start, hi, side="left"))
        starts, ends = self.run_start[r0:r1], self.run_end[r0:r1]
        ka, kb = np.maximum(starts, lo), np.minimum(ends - 2 * m + 1, hi)
        ok = kb > ka
        ka, kb = ka[ok], kb[ok]
        kept = int(np.sum(kb - ka))
        if kept == 0:
            return  # adding einsum's +0 would change nothing
        # Only the kept points, compiled: the points zeroed in the numpy form added +0 to a
        # sum of squares (unchanged), the rest the same operations in the same order.
        self.total[j] += _kernels().kept_sum(S, o, m, ka, kb)
        self.count[j] += kept


@dataclass(frozen=True)
class NoiseFit:
    """The fitted noise terms of one column (``None``: not determined by this curve)."""

    white: float | None  # N: sqrt(avar) on the slope -1/2 line at tau = 1 s, unit sqrt(s)
    random_walk: float | None  # K: on the slope +1/2 line at tau = 3 s, unit / sqrt(s)
    white_rel_err: float | None  # about one standard error of N, relative
    random_walk_rel_err: float | None
    bias_instability: float | None  # min adev / 0.664, unit
    tau_min_adev: float  # s, where the deviation is smallest
    min_adev: float
    fit_from_tau: float  # s, the shortest tau used in the fit
    flat: float  # the constant term c of the fit (variance)
    why: tuple[str, ...]  # why a figure is missing


def fit_noise(curve: AllanCurve, dt: float, column: int = 0) -> NoiseFit:
    """Fit ``N^2/tau + c + K^2 tau/3`` to one column of the curve (non-negative least squares,
    each lag's relative error weighted by the square root of its degrees of freedom).

    The fit starts at the first lag whose log-log slope to the next lies in [-0.75, -0.35]: at
    shorter lags an anti-alias filter (slope above -1/2) or quantisation (slope -1) shapes the
    curve, not the white noise. ``N`` counts as determined when the white term dominates the
    fitted model at the shortest fitted lag, ``K`` when the random-walk term dominates at the
    longest, the bias instability when the deviation rises again after its minimum by more than
    twice its own scatter there.
    """
    taus = curve.lags * float(dt)
    av = curve.avar[:, column]
    edf = curve.edf()
    why: list[str] = []
    good = np.isfinite(av) & (av > 0)
    taus, av, edf = taus[good], av[good], edf[good]
    if len(taus) == 0:
        return NoiseFit(None, None, None, None, None, float("nan"), float("nan"),
                        float("nan"), 0.0, ("no lag with a positive variance",))
    slopes = 0.5 * np.diff(np.log(av)) / np.diff(np.log(taus))  # of the deviation
    white_like = np.flatnonzero((slopes >= -0.75) & (slopes <= -0.35))
    i0 = int(white_like[0]) if len(white_like) else 0
    t, a, e = taus[i0:], av[i0:], edf[i0:]
    design = np.column_stack([1.0 / t, np.ones_like(t), t / 3.0])
    w = np.sqrt(e) / a
    from scipy.optimize import nnls  # here, where it runs: ~0.2 s CPU to import

    coef, _ = nnls(design * w[:, None], a * w)
    n2, c, k2 = (float(v) for v in coef)
    model = design @ coef
    rel = _relative_errors(design, coef, model, e)
    white = np.sqrt(n2) if n2 > 0 and n2 / t[0] > 0.5 * model[0] else None
    if white is None:
        why.append("white noise: no lag where the -1/2 slope dominates")
    rw = np.sqrt(k2) if k2 > 0 and k2 * t[-1] / 3.0 > 0.5 * model[-1] else None
    if rw is None:
        why.append(f"random walk: no +1/2 slope up to tau = {t[-1]:.3g} s (record too short)")
    dev = np.sqrt(av)
    i_min = int(np.argmin(dev))
    scatter = 1.0 / np.sqrt(2.0 * edf)  # relative standard error of a deviation estimate
    after = dev[i_min + 1:]
    rises = len(after) > 0 and bool(np.any(after > dev[i_min] * (1.0 + 2.0 * scatter[i_min + 1:])))
    bi = dev[i_min] / BIAS_INSTABILITY_FACTOR if rises else None
    if bi is None:
        why.append(f"bias instability: the deviation does not turn up again by tau = "
                   f"{taus[-1]:.3g} s (its flat minimum is not reached)")
    return NoiseFit(white=white, random_walk=rw,
                    white_rel_err=None if white is None else rel[0],
                    random_walk_rel_err=None if rw is None else rel[2], bias_instability=bi,
                    tau_min_adev=float(taus[i_min]), min_adev=float(dev[i_min]),
                    fit_from_tau=float(t[0]), flat=c, why=tuple(why))


def _relative_errors(design: np.ndarray, coef: np.ndarray, model: np.ndarray,
                     edf: np.ndarray) -> np.ndarray:
    """About one standard error of sqrt(coef), relative, from the weighted least-squares
    covariance (each lag's variance known to sqrt(2 / edf) of itself), widened by
    CORRELATION_FACTOR; nan for a coefficient at zero."""
    out = np.full(len(coef), np.nan)
    active = coef > 0
    if not np.any(active):
        return out
    w = np.sqrt(edf / 2.0) / model
    a = (design * w[:, None])[:, active]
    cov = np.linalg.pinv(a.T @ a)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    out[active] = CORRELATION_FACTOR * 0.5 * sd / coef[active]
    return out


def _kernels():
    """The compiled loops, imported on first use: numba costs ~0.7 s of CPU to import, not
    paid by a command that computes no noise figures (``--help``, the viewer of a .rrd)."""
    from imucal.numerics import allan_kernels

    return allan_kernels
