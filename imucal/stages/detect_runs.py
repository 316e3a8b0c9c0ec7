"""The tuner's passes over the statistic (method.md §1, M1), a span at a time (issue 12).

* :func:`window_pass`: what one window's M1 tells the scan of thresholds, in one pass: its
  largest value in each bin of a few samples, a strided sample for the quiet level, its values
  at the outliers, and how many samples lie below each threshold tried.
* :func:`still_runs`: where ``s2 < threshold`` and, with a local factor, where each such
  stretch stays under that factor times its own median; on an array (the scan's bins) or
  streamed from the spans of M1 at full resolution (:func:`streamed_still_runs`).

The streamed runs are those of the array formula to the bit: each run's median is taken from
the same sample of its values (every ``step``-th, ``step`` from the total still length the
window pass counted), and checked against the array formula's own sort of all of them at the
end; a run whose M1 had to be let go before its median was known (longer than
:data:`OPEN_LIMIT`), or whose median that check corrects, is redone over its spans alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from imucal.numerics.windows import CHUNK_ROWS, runs_of_true
from imucal.stages.detect_stat import SPAN, Statistic

MEDIAN_VALUES = 200_000  # values of M1 a run median is taken from, at most, over all runs
OPEN_LIMIT = 4 * SPAN  # M1 values kept for a still run not yet ended (longer: redone)
QUIET_VALUES = 500_000  # values of M1 the quiet level is taken from, about


@dataclass(frozen=True)
class WindowPass:
    """One window's M1 as the scan needs it (the values themselves are not kept)."""

    window: int
    per: int  # samples per bin
    binmax: np.ndarray  # (ceil(n / per),) the largest M1 of each bin; the last partial one inf
    sample: np.ndarray  # M1 at every max(1, n // QUIET_VALUES)-th sample
    at_outliers: np.ndarray  # M1 at the outlier samples
    thresholds: np.ndarray | None  # ascending; None: unknown during the pass
    below: np.ndarray | None  # per threshold: samples, outliers aside, where M1 < it

    def still_samples(self, threshold: float) -> int | None:
        """Samples (outliers aside) where M1 < ``threshold``, if it was counted."""
        if self.thresholds is None:
            return None
        hit = np.flatnonzero(self.thresholds == threshold)
        return int(self.below[hit[0]]) if len(hit) else None


def window_pass(stat: Statistic, per: int, outliers: np.ndarray,
                thresholds: np.ndarray | None = None) -> WindowPass:
    """One pass over M1 (see the module's docstring)."""
    n = stat.n
    stride = max(1, n // QUIET_VALUES)
    nb = -(-n // per)
    binmax = np.empty(nb)
    carry, held = -np.inf, 0  # the largest value of the bin still open, and its samples so far
    sample, at_out = [], np.empty(len(outliers))
    counts = None if thresholds is None else np.zeros(len(thresholds), np.int64)
    for o0, o1, s in stat.spans():
        p, length = 0, o1 - o0
        if held:  # the bin the last span left open
            p = min(per - held, length)
            carry = np.maximum(carry, s[:p].max())
            held += p
            if held == per:
                binmax[(o0 + p - 1) // per], carry, held = carry, -np.inf, 0
        q = (length - p) // per
        if q:
            first = (o0 + p) // per
            binmax[first:first + q] = s[p:p + q * per].reshape(q, per).max(axis=1)
            p += q * per
        if p < length:
            carry, held = s[p:].max(), length - p
        sample.append(s[(-o0) % stride::stride].copy())
        i0, i1 = np.searchsorted(outliers, [o0, o1])
        at_out[i0:i1] = s[outliers[i0:i1] - o0]
        if counts is not None:  # one vectorised count per threshold beats a search per value
            counts += [np.count_nonzero(s < thr) for thr in thresholds]
    if held:  # a partial last bin is never still
        binmax[nb - 1] = np.maximum(carry, np.inf)
    below = None
    if counts is not None:
        below = counts - np.array([np.count_nonzero(at_out < thr) for thr in thresholds])
    return WindowPass(window=stat.window, per=per, binmax=binmax, sample=np.concatenate(sample),
                      at_outliers=at_out, thresholds=thresholds, below=below)


def values_at(stat: Statistic, idx: np.ndarray) -> np.ndarray:
    """M1 at the sorted sample indices ``idx``: only the spans holding one are computed."""
    idx = np.asarray(idx, dtype=np.int64)
    out = np.empty(len(idx))

    def wanted(o0: int, o1: int) -> bool:
        i0, i1 = np.searchsorted(idx, [o0, o1])
        return bool(i1 > i0)

    if len(idx):
        for o0, o1, s in stat.spans(only=wanted):
            i0, i1 = np.searchsorted(idx, [o0, o1])
            out[i0:i1] = s[idx[i0:i1] - o0]
    return out


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
    median = run_medians(values, runs)
    lengths = runs[:, 1] - runs[:, 0]
    ends = np.cumsum(lengths)
    i = 0
    while i < len(runs):  # runs of runs of about CHUNK_ROWS samples: small index arrays
        j = max(i + 1, int(np.searchsorted(ends, ends[i] - lengths[i] + CHUNK_ROWS, "right")))
        idx = run_indices(runs[i:j])
        mask[idx] = values[idx] < local * np.repeat(median[i:j], lengths[i:j])
        i = j
    return runs_of_true(mask)


def run_indices(runs: np.ndarray, step: int = 1) -> np.ndarray:
    """Every ``step``-th index of each [start, end) run, concatenated in order."""
    lengths = -(-(runs[:, 1] - runs[:, 0]) // step)
    offsets = np.repeat(runs[:, 0] - (np.cumsum(lengths) - lengths) * step, lengths)
    return offsets + np.arange(int(lengths.sum())) * step


def median_step(runs: np.ndarray) -> int:
    """Every how many values a run's median is taken from (M1 is smooth over a window: every
    step-th value tells its median as well)."""
    return max(1, int((runs[:, 1] - runs[:, 0]).sum()) // MEDIAN_VALUES)


def run_medians(values: np.ndarray, runs: np.ndarray) -> np.ndarray:
    """The median of ``values`` over each run, from every :func:`median_step`-th of them."""
    step = median_step(runs)
    return medians_of(values[run_indices(runs, step)], -(-(runs[:, 1] - runs[:, 0]) // step))


def medians_of(v: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """The (lower) median of each of the consecutive groups of ``lengths`` values of ``v``.

    One sort by group, then by value: the group's number plus its log value squeezed into
    [0, 0.5) (an argsort of floats is several times faster than a lexsort of two keys)."""
    logv = np.log(np.maximum(v, np.finfo(float).tiny))
    lo, hi = float(logv.min()), float(logv.max())
    key = (logv - lo) * (0.5 / max(hi - lo, 1e-300))
    key += np.repeat(np.arange(len(lengths), dtype=float), lengths)
    order = np.argsort(key)
    first = np.cumsum(lengths) - lengths
    return v[order[first + (lengths - 1) // 2]]


def streamed_still_runs(stat: Statistic, threshold: float, local: float | None,
                        outliers: np.ndarray, total: int | None = None) -> np.ndarray:
    """:func:`still_runs` of M1 at every sample, from its spans: ``total`` is the number of
    samples, outliers aside, where M1 < ``threshold`` (:meth:`WindowPass.still_samples`;
    None: counted in a pass of its own first)."""
    if local is None:
        return _plain_runs(stat, threshold, outliers)
    if total is None:
        total = int(np.sum(np.diff(_plain_runs(stat, threshold, outliers), axis=1)))
    found = _LocalRuns(threshold, local, outliers, max(1, total // MEDIAN_VALUES)).scan(stat)
    if found is None:  # the count was not the runs' (it cannot be): redo with theirs
        runs = _plain_runs(stat, threshold, outliers)
        return streamed_still_runs(stat, threshold, local, outliers,
                                   int(np.sum(runs[:, 1] - runs[:, 0])))
    return found


def _plain_runs(stat: Statistic, threshold: float, outliers: np.ndarray) -> np.ndarray:
    """Runs of ``M1 < threshold`` with the outliers ending them, joined across spans."""
    return _joined([_span_runs(s, o0, threshold, outliers) for o0, _, s in stat.spans()])


def _joined(parts: list[np.ndarray]) -> np.ndarray:
    """The runs of consecutive pieces, one run where one ends as the next begins (at a span's
    edge: within a span the runs are apart)."""
    runs = np.concatenate([np.zeros((0, 2), np.int64), *parts]).astype(np.int64)
    if len(runs) < 2:
        return runs
    first = np.flatnonzero(np.r_[True, runs[1:, 0] != runs[:-1, 1]])
    last = np.r_[first[1:] - 1, len(runs) - 1]
    return np.column_stack([runs[first, 0], runs[last, 1]])


def _span_runs(s: np.ndarray, o0: int, threshold: float, outliers: np.ndarray) -> np.ndarray:
    mask = s < threshold
    i0, i1 = np.searchsorted(outliers, [o0, o0 + len(s)])
    mask[outliers[i0:i1] - o0] = False
    return runs_of_true(mask).astype(np.int64) + o0


class _LocalRuns:
    """The streamed runs with local ends, a span at a time: the runs inside a span all at once
    (their samples of values, candidate medians and comparisons, vectorised); a run across
    spans gathered as they go by and compared with its median when it ends (its values held
    up to OPEN_LIMIT). The candidates are checked against :func:`medians_of` of every run's
    sample at the end, and the runs it corrects, or whose values were let go, redone."""

    def __init__(self, threshold: float, local: float, outliers: np.ndarray, step: int):
        self.threshold, self.local, self.outliers, self.step = threshold, local, outliers, step
        self.runs: list[np.ndarray] = []  # (r, 2) batches of runs, in order
        self.values: list[np.ndarray] = []  # their samples of values, in order
        self.medians: list[np.ndarray] = []  # their candidate medians
        self.pieces: list[np.ndarray] = []  # refined runs, (p, 3): start, end, run number
        self.count = 0  # runs so far
        self.let_go: list[int] = []  # runs whose values were not held: redone
        self.open: dict | None = None

    def scan(self, stat: Statistic) -> np.ndarray | None:
        for o0, o1, s in stat.spans():
            runs = _span_runs(s, o0, self.threshold, self.outliers)
            if self.open is not None:
                if len(runs) and runs[0, 0] == o0 and self.open["end"] == o0:
                    self._extend(s, o0, int(runs[0, 0]), int(runs[0, 1]))
                    runs = runs[1:]
                if self.open["end"] < o1 or len(runs):
                    self._close()
            tail = None
            if len(runs) and runs[-1, 1] == o1:  # may go on into the next span
                tail, runs = runs[-1], runs[:-1]
            if len(runs):
                self._inside(s, o0, runs)
            if tail is not None:
                self.open = {"start": int(tail[0]), "end": int(tail[0]), "values": [],
                             "held": [], "n": 0}
                self._extend(s, o0, int(tail[0]), int(tail[1]))
        if self.open is not None:
            self._close()
        if self.count == 0:
            return np.zeros((0, 2), np.int64)
        runs = np.concatenate(self.runs)
        starts, ends = runs[:, 0], runs[:, 1]
        if max(1, int(np.sum(ends - starts)) // MEDIAN_VALUES) != self.step:
            return None
        exact = medians_of(np.concatenate(self.values), -(-(ends - starts) // self.step))
        redo = np.union1d(np.flatnonzero(exact != np.concatenate(self.medians)),
                          np.asarray(self.let_go, np.int64)).astype(np.int64)
        pieces = np.concatenate([np.zeros((0, 3), np.int64), *self.pieces])
        if len(redo):
            pieces = pieces[~np.isin(pieces[:, 2], redo)]
            pieces = np.concatenate([pieces, self._redo(stat, starts, ends, exact, redo)])
            pieces = pieces[np.argsort(pieces[:, 0], kind="stable")]
        return pieces[:, :2].copy()

    def _inside(self, s: np.ndarray, o0: int, runs: np.ndarray) -> None:
        """Runs that begin and end in this span, all at once."""
        rel = runs - o0
        lengths = rel[:, 1] - rel[:, 0]
        v = s[run_indices(rel, self.step)]
        median = medians_of(v, -(-lengths // self.step))  # candidates (keys of this span)
        where = run_indices(rel)
        still = np.zeros(len(s), dtype=bool)
        still[where] = s[where] < self.local * np.repeat(median, lengths)
        found = runs_of_true(still).astype(np.int64)
        number = self.count + np.searchsorted(rel[:, 0], found[:, 0], side="right") - 1
        self.pieces.append(np.column_stack([found + o0, number]))
        self.runs.append(runs.astype(np.int64))
        self.values.append(v)
        self.medians.append(median)
        self.count += len(runs)

    def _extend(self, s: np.ndarray, o0: int, a: int, b: int) -> None:
        run, step = self.open, self.step
        first = run["start"] + -(-(a - run["start"]) // step) * step
        run["values"].append(s[first - o0:b - o0:step].copy())
        if run["held"] is not None:
            run["held"].append(s[a - o0:b - o0])
            run["n"] += b - a
            if run["n"] > OPEN_LIMIT:
                run["held"] = None  # let go: redone once its median is known
        run["end"] = b

    def _close(self) -> None:
        run, self.open = self.open, None
        v = np.concatenate(run["values"])
        median = np.partition(v, (len(v) - 1) // 2)[(len(v) - 1) // 2]
        if run["held"] is None:
            self.let_go.append(self.count)
        else:
            still = np.concatenate(run["held"]) < self.local * median
            found = runs_of_true(still).astype(np.int64) + run["start"]
            self.pieces.append(np.column_stack([found, np.full(len(found), self.count)]))
        self.runs.append(np.array([[run["start"], run["end"]]], np.int64))
        self.values.append(v)
        self.medians.append(np.array([median]))
        self.count += 1

    def _redo(self, stat: Statistic, starts: np.ndarray, ends: np.ndarray, medians: np.ndarray,
              redo: np.ndarray) -> np.ndarray:
        """The runs ``redo`` compared with their exact medians over the spans they cover:
        their refined runs, each with its run's number."""
        rs, re = starts[redo], ends[redo]

        def wanted(o0: int, o1: int) -> bool:
            return bool(np.any((rs < o1) & (re > o0)))

        found: dict[int, list[np.ndarray]] = {int(i): [] for i in redo}
        for o0, o1, s in stat.spans(only=wanted):
            for i in redo[(rs < o1) & (re > o0)].tolist():
                a, b = max(starts[i], o0), min(ends[i], o1)
                still = s[a - o0:b - o0] < self.local * medians[i]
                found[i].append(runs_of_true(still).astype(np.int64) + a)
        out = [np.zeros((0, 3), np.int64)]
        for i, parts in found.items():
            r = _joined(parts)
            out.append(np.column_stack([r, np.full(len(r), i)]))
        return np.concatenate(out)
