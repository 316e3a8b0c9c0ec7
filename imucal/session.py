"""The session: raw accelerometer and gyroscope signals with their timestamps and units."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from imucal.numerics.order_stats import Chunks, ranked_values
from imucal.streams import Stream, first_of_kind

ACC_UNITS = ("g", "m/s^2", "counts")
GYRO_UNITS = ("rad/s", "deg/s", "counts")
STANDARD_GRAVITY = 9.80665


@dataclass(frozen=True)
class Session:
    """A recording to calibrate (method.md §0).

    ``acc`` is (N, 3) with timestamps ``t_acc`` (N,) in seconds, strictly increasing; ``gyro``
    is (M, 3) with ``t_gyro`` (M,), or both ``None`` for an accelerometer-only session. The
    two sensors may run at different rates. Gyroscope data given in deg/s is converted to rad/s
    on load, so ``gyro_unit`` is ``"rad/s"`` or ``"counts"``.
    """

    acc: np.ndarray
    t_acc: np.ndarray
    gyro: np.ndarray | None = None
    t_gyro: np.ndarray | None = None
    acc_unit: str = "g"
    gyro_unit: str | None = "rad/s"
    source: str = "<memory>"
    sha256: str = ""
    notes: tuple[str, ...] = field(default_factory=tuple)
    # The initial still period the file states (s), a hint for the static detector (method.md
    # §1); None where the file says nothing.
    init_still_s: float | None = None
    # Where the signals are held when not in the process's memory (a long recording's arrays
    # mapped from a temporary file, imucal.io.spill), for the report; None: in memory.
    storage: str | None = None
    # A recording of many streams (imucal.streams): which accelerometer and gyroscope were taken
    # and from where (one line each, for calib.json and the report), and the streams the file
    # holds beside them (a magnetometer, a thermometer, other IMUs). Empty for a table of one
    # accelerometer and one gyroscope.
    chosen: tuple[str, ...] = ()
    others: tuple[Stream, ...] = ()

    def __post_init__(self) -> None:
        if self.acc_unit not in ACC_UNITS:
            raise ValueError(f"acc_unit must be one of {ACC_UNITS}, got {self.acc_unit!r}")
        if self.gyro is not None and self.gyro_unit not in ("rad/s", "counts"):
            raise ValueError(f"gyro_unit must be 'rad/s' or 'counts', got {self.gyro_unit!r}")

    @property
    def magnetometer(self) -> Stream | None:
        """The magnetometer calibrated beside the pair (stages/mag.py): the first of
        :attr:`others`, where the loader puts the one ``--mag`` names; None without one."""
        return first_of_kind(self.others, "mag")

    @property
    def has_gyro(self) -> bool:
        return self.gyro is not None and len(self.gyro) > 0

    @cached_property
    def acc_step(self) -> float:
        """Median step of the accelerometer's clock (s): ``np.median(np.diff(t_acc))`` to the
        bit, without the signal-sized steps and median's copy of them (issue 12: 346 MB at 6
        hours of 1 kHz). Computed once per session (each pass re-reads the whole clock, a
        spilled one from disk): the detector, the sanity checks, the guide and the report all
        ask for it. A session is frozen, so the value cannot go stale; ``dataclasses.replace``
        makes a new session that computes its own."""
        return median_step(self.t_acc, [(0, len(self.t_acc))])  # row slices only

    @cached_property
    def gyro_step(self) -> float | None:
        """Median step of the gyroscope's clock (s), as :attr:`acc_step`; the accelerometer's
        own when the two share one time array."""
        if not self.has_gyro:
            return None
        if self.t_gyro is self.t_acc:
            return self.acc_step
        return median_step(self.t_gyro, [(0, len(self.t_gyro))])

    @property
    def acc_rate(self) -> float:
        """Median sample rate of the accelerometer in Hz: ``1 / np.median(np.diff(t_acc))``
        to the bit (:attr:`acc_step`)."""
        return float(1.0 / self.acc_step)

    @property
    def gyro_rate(self) -> float | None:
        if not self.has_gyro:
            return None
        return float(1.0 / self.gyro_step)

    @property
    def duration(self) -> float:
        return float(self.t_acc[-1] - self.t_acc[0])


def median_step(t: np.ndarray, ranges: Iterable[tuple[int, int]]) -> float:
    """``np.median(np.concatenate([np.diff(t[a:b]) for a, b in ranges]))`` to the bit, without
    the steps of the whole clock (see :func:`chunked_median`)."""
    ranges = [(int(a), int(b)) for a, b in ranges]
    return chunked_median(diff_chunks(t, ranges), sum(max(b - a - 1, 0) for a, b in ranges))


# --- an exact median of values given a chunk at a time (issue 12) --------------------------------
# np.median of the values to the bit without holding them all: the middle ranks come from
# imucal.numerics.order_stats (a sampled bracket and a counting pass); below MEDIAN_SMALL
# values, or where the bracket misses, np.median makes its copy.

MEDIAN_SMALL = 1 << 20  # values: below this, the copy is cheap and np.median makes it
MEDIAN_SAMPLE = 1 << 17  # values in the bracket's sample, about


def chunked_median(chunks: Chunks, n: int, small: int = MEDIAN_SMALL) -> float:
    """``np.median`` of the ``n`` values that ``chunks()`` yields (1-D arrays, in order; called
    once per pass, so it must start afresh each time)."""
    if n < small:
        return float(np.median(_whole(chunks)))
    got = ranked_values(chunks, n, [[(n - 1) // 2, n // 2]], MEDIAN_SAMPLE)
    if got is None:
        return float(np.median(_whole(chunks)))
    m0, m1 = got[0]
    if n % 2:
        return float(m1)
    return float(np.mean(np.array([m0, m1])))  # numpy's median: the mean of the middle two


def _whole(chunks: Chunks) -> np.ndarray:
    parts = list(chunks())
    return np.concatenate(parts) if parts else np.zeros(0)


def diff_chunks(t: np.ndarray, ranges: Iterable[tuple[int, int]],
                rows: int = 1 << 16) -> Chunks:
    """The steps ``np.diff(t[a:b])`` of each range, end to end, ``rows`` steps at a time (for
    :func:`chunked_median`)."""
    ranges = [(int(a), int(b)) for a, b in ranges]

    def gen() -> Iterable[np.ndarray]:
        for a, b in ranges:
            for s in range(a, b - 1, rows):
                yield np.diff(t[s:min(s + rows + 1, b)])

    return gen


def chunks_all(x: np.ndarray, test, overlap: int = 0, rows: int = 1 << 18) -> bool:
    """``np.all(test(x))`` a chunk of rows at a time (``overlap`` rows shared with the next,
    for a test on steps): no temporary the length of a long recording."""
    return all(bool(np.all(test(x[lo:lo + rows + overlap])))
               for lo in range(0, max(len(x) - overlap, 1), rows))


def validate(session: Session) -> None:
    """Refuse a session the method cannot use, in one line naming the field.

    The loaders check files as they read them; this guards sessions built in code.
    """
    from imucal.errors import ImucalError

    def check(x: np.ndarray | None, t: np.ndarray | None, name: str) -> None:
        if x is None:
            return
        x = np.asarray(x)
        if x.ndim != 2 or x.shape[1] != 3:
            raise ImucalError(f"expected an (N, 3) array, got shape {x.shape}",
                              source=session.source, field=name)
        if t is None or np.asarray(t).shape != (len(x),):
            raise ImucalError(f"expected one timestamp per sample ({len(x)})",
                              source=session.source, field=f"{name} time")
        if not np.issubdtype(x.dtype, np.number) or not chunks_all(x, np.isfinite):
            raise ImucalError("samples must be finite numbers (NaN or Inf found)",
                              source=session.source, field=name)
        t = np.asarray(t, dtype=float)
        if (len(t) < 2 or not chunks_all(t, np.isfinite)
                or not chunks_all(t, lambda c: np.diff(c) > 0, overlap=1)):
            raise ImucalError("timestamps must be finite and strictly increasing",
                              source=session.source, field=f"{name} time")

    check(session.acc, session.t_acc, "accelerometer")
    check(session.gyro, session.t_gyro, "gyroscope")
