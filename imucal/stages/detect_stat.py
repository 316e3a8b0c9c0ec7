"""The static detector's statistic (method.md §1, equation M1) a span of samples at a time.

``s2(t) = var_x(t)^2 + var_y(t)^2 + var_z(t)^2`` over a centred window, on the accelerometer with
its isolated outliers replaced by the mean of their neighbours (:class:`CleanRows`). A 6-hour
recording at 1 kHz has 21.6 million values of it (173 MB): nothing keeps them all. The spans of
:func:`statistic_spans` are computed one after the other from the rows they need (a span plus a
window), each exactly as the whole-signal computation computed it, so every pass over them (the
tuner's, the viewer's) sees the same values to the bit.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import numpy as np

from imucal.errors import ImucalError
from imucal.numerics.rows import floats
from imucal.numerics.windows import rolling_variance, variance_sumsq

SPAN = 1 << 17  # M1 values computed at once (a span of rows and a window, in six rows)
KINDS = ("thesis", "imu_tk")

Rows = Callable[[int, int], np.ndarray]  # rows(a, b): float64 rows [a, b), a fresh array


class CleanRows:
    """The rows M1 is computed on: the accelerometer's with each isolated outlier replaced by
    the mean of its two neighbours (the first and last samples by their one), read a block at
    a time from ``x`` (slices, and one gather of the outliers' neighbours)."""

    def __init__(self, x, outliers: np.ndarray):
        self.x = x
        self.n = len(x)
        self.width = int(x.shape[1])
        self.outliers = np.asarray(outliers, dtype=np.int64)
        o, n = self.outliers, self.n
        self.values = np.zeros((0, self.width))
        if len(o):
            lo = np.where(o > 0, o - 1, o + 1)
            hi = np.where(o < n - 1, o + 1, o - 1)
            self.values = 0.5 * (np.asarray(x[lo], dtype=np.float64)
                                 + np.asarray(x[hi], dtype=np.float64))

    def __len__(self) -> int:
        return self.n

    @property
    def shape(self) -> tuple[int, int]:
        return (self.n, self.width)

    ndim = 2
    dtype = np.dtype(np.float64)

    def __getitem__(self, key) -> np.ndarray:
        """Rows by a slice (``clean[a:b]``) or a gather of sorted indices."""
        if isinstance(key, slice) and key.step in (None, 1):
            a, b, _ = key.indices(self.n)
            return self(a, max(a, b))
        idx = np.asarray(key, dtype=np.int64)
        out = np.array(self.x[idx], dtype=np.float64)
        if len(self.outliers) and len(idx):
            pos = np.minimum(np.searchsorted(self.outliers, idx), len(self.outliers) - 1)
            hit = self.outliers[pos] == idx
            out[hit] = self.values[pos[hit]]
        return out

    def __call__(self, a: int, b: int) -> np.ndarray:
        out = np.array(self.x[a:b], dtype=np.float64)  # our own copy: outliers are written
        if len(self.outliers):
            i0, i1 = np.searchsorted(self.outliers, [a, b])
            out[self.outliers[i0:i1] - a] = self.values[i0:i1]
        return out


def check_kind(statistic: str) -> None:
    if statistic not in KINDS:
        raise ImucalError(f"unknown static statistic {statistic!r}; expected 'thesis' or "
                          "'imu_tk'", source="settings", field="statistic")


def combine_variances(var: np.ndarray, statistic: str) -> np.ndarray:
    """M1 from per-axis variances: ``var_x^2 + var_y^2 + var_z^2`` (the thesis), or its square
    root (imu_tk's norm of the variances)."""
    check_kind(statistic)
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


def statistic_spans(rows: Rows, n: int, width: int, window: int, statistic: str = "thesis",
                    span: int | None = None, only: Callable[[int, int], bool] | None = None
                    ) -> Iterator[tuple[int, int, np.ndarray]]:
    """``(o0, o1, s2[o0:o1])`` for the spans of ``span`` samples in order (``only(o0, o1)``
    False: that span is skipped, not computed), M1 over ``window`` samples of the ``n`` rows
    of ``width`` columns that ``rows(a, b)`` gives.

    Each span's rows (with half a window on either side, mirrored at the ends) are centred on
    their own mean before the running sums of :func:`chunked_window_sums`, every axis at once:
    the temporaries are a span's, and the values those of the whole-signal computation this
    replaces. A recording of at most two spans is one, through :func:`rolling_variance`. A
    variance too large for floating point is infinite: not still, and said quietly.
    """
    check_kind(statistic)
    span = SPAN if span is None else span  # read here: a test may make the spans small
    w = int(window)
    left = w // 2
    with np.errstate(over="ignore", invalid="ignore"):
        if n <= max(left, w - 1 - left) or n <= 2 * span:
            if only is None or only(0, n):
                yield 0, n, combine_variances(rolling_variance(rows(0, n), w), statistic)
            return
        k = int(width)
        b = max(16384, 2 * w)
        y = np.empty((k, 0))  # a span's rows, each contiguous; reused: no fresh pages a span
        for o0 in range(0, n, span):
            o1 = min(n, o0 + span)
            if only is not None and not only(o0, o1):
                continue
            z = _mirrored(rows, n, o0 - left, o1 - left + w - 1)  # the samples these need
            if y.shape[1] != len(z):
                y = np.empty((k, len(z)))
            y[:] = z.T
            y -= y.mean(axis=1, keepdims=True)
            # M1 from the running sums of the centred rows and their squares, compiled
            # (the same operations as chunked_window_sums and combine_variances, in order)
            yield o0, o1, variance_sumsq(y, w, o1 - o0, b, root=statistic != "thesis")


def _mirrored(rows: Rows, n: int, a: int, c: int) -> np.ndarray:
    """Rows ``[a, c)`` of the signal mirrored about its first and last sample (row ``-i`` is
    row ``i``, row ``n - 1 + i`` is row ``n - 1 - i``): slices, reversed where mirrored."""
    if a >= 0 and c <= n:
        return rows(a, c)
    parts = []
    if a < 0:
        parts.append(rows(1, 1 - a)[::-1])
    parts.append(rows(max(a, 0), min(c, n)))
    if c > n:
        parts.append(rows(2 * n - 1 - c, n - 1)[::-1])
    return np.concatenate(parts)


def rolling_statistic(x, window: int, statistic: str = "thesis", span: int = SPAN
                      ) -> np.ndarray:
    """M1 at every sample of ``x`` (n, k), or of a :class:`CleanRows`: the spans of
    :func:`statistic_spans` put together (for a reader that wants them all, as the viewer)."""
    check_kind(statistic)
    rows = x if isinstance(x, CleanRows) else (lambda a, b: floats(x, a, b))
    n = len(x)
    out = np.empty(n)
    for o0, o1, s in statistic_spans(rows, n, int(x.shape[1]), window, statistic, span):
        out[o0:o1] = s
    return out


class Statistic:
    """M1 over one window of the clean rows, as spans (:func:`statistic_spans`): computed on
    every request, never kept."""

    def __init__(self, rows: CleanRows, window: int, kind: str = "thesis"):
        check_kind(kind)
        self.rows, self.window, self.kind = rows, int(window), kind

    @property
    def n(self) -> int:
        return self.rows.n

    def spans(self, only: Callable[[int, int], bool] | None = None
              ) -> Iterator[tuple[int, int, np.ndarray]]:
        return statistic_spans(self.rows, self.rows.n, self.rows.width, self.window,
                               self.kind, span=SPAN, only=only)
