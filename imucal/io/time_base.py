"""The time base of a recording (method.md §0): timestamps in seconds from a time column or a
rate, checked to increase, and short runs of missing samples bridged."""

from __future__ import annotations

import numpy as np

from imucal.errors import ImucalError, plural
from imucal.io.column_names import LABELS
from imucal.io.parts import LoadOptions, Part
from imucal.io.spill import Empty, elementwise
from imucal.io.units import TIME_UNITS
from imucal.session import chunks_all

MAX_RATE_HZ = 100_000.0
# One sample a minute: below it no recording is an IMU's, and a rate such as 1e-300 only
# overflows the timestamps (issue 27: it ended in an internal error).
MIN_RATE_HZ = 1 / 60
MAX_BRIDGED_RUN = 5  # longest run of non-finite samples that is interpolated instead of refused
MAX_BRIDGED_FRACTION = 0.05  # and at most this share of a recording may be interpolated
NUMBERED_NOTE = ("no time column and no rate: t is the sample number (0, 1, 2, ...), which a "
                 "calibration of one segment does not use")
RATE_TOLERANCE = 0.01  # a stated rate further than this from the one used is a note


def own_rows(acc: Part, gyro: Part, opts: LoadOptions) -> None:
    """Two sensors on rows of their own in one timed table (two logs merged on time: each row
    holds one sensor's values and leaves the other's empty): each sensor keeps its own rows.

    Only when many rows hold one sensor and not the other; a row missing both, or a few
    missing values, stay for the gap bridging (or its refusal) as before."""
    if (acc.time is None or gyro.time is None or len(acc.values) != len(gyro.values)
            or not (acc.time is gyro.time or np.array_equal(acc.time, gyro.time,
                                                            equal_nan=True))):
        return  # not rows of one table
    if chunks_all(acc.values, np.isfinite, 0) and chunks_all(gyro.values, np.isfinite, 0):
        return  # every row holds both (the common case: no row-wise masks needed)
    has_a = np.isfinite(acc.values).any(axis=1)
    has_g = np.isfinite(gyro.values).any(axis=1)
    n = len(has_a)
    one_only = np.count_nonzero(has_a != has_g)
    if one_only <= max(MAX_BRIDGED_RUN, MAX_BRIDGED_FRACTION * n):
        return
    for part, own in ((acc, has_a), (gyro, has_g)):
        part.values, part.time = part.values[own], part.time[own]
    opts.notes.append(f"{acc.source}: the accelerometer and the gyroscope are on rows of their "
                      f"own ({int(has_a.sum())} and {int(has_g.sum())} of {n}); each sensor "
                      "keeps its own rows and timestamps")


def settle_time(part: Part, opts: LoadOptions, empty: Empty = np.empty
                ) -> tuple[np.ndarray, np.ndarray]:
    """Checked timestamps in seconds (from the file, else the rate); short NaN gaps bridged.
    ``empty`` allocates timestamps made here (mapped when long, :mod:`imucal.io.spill`).

    The rate is the user's, else the one the file's preamble states; a time column wins over
    both, and a stated rate it contradicts by more than 1 % is a note."""
    label, source = LABELS[part.sensor], part.source
    values = part.values
    n = len(values)
    if n < 2:
        raise ImucalError(f"{label}: {n} sample(s); at least 2 are needed", source=source,
                          field="samples")
    rate, rate_from = _rate(part, opts)
    time = part.time
    if time is not None and _counts_samples(time, part, opts):
        # 0, 1, 2, ... read as seconds would be a 1 Hz IMU: it is a sample counter.
        if rate is None:
            first = ", ".join(f"{v:g}" for v in time[:3])
            raise ImucalError(f"{part.time_label} goes up in steps of 1 ({first}, ...): a sample "
                              "counter, not seconds; give the sample rate with --rate HZ, or "
                              "--time-unit ms (us, ns) if it counts milliseconds",
                              source=source, field="rate")
        opts.notes.append(f"{part.time_label} of {source} counts samples (steps of 1); "
                          f"timestamps from the rate {rate:g} Hz{rate_from}")
        time = None
    if time is not None:
        unit = _time_unit(part, opts)
        if unit == "s" and part.time_unit is None and not part.time_is_datetime:
            unit = _unit_from_steps(time, part, opts)
        if TIME_UNITS[unit] == 1.0 and time.dtype == np.float64:
            t = time  # seconds already: no signal-sized copy (x * 1.0 == x)
        else:
            scale = TIME_UNITS[unit]
            with np.errstate(over="ignore", invalid="ignore"):  # non-finite: refused below
                t = elementwise(lambda x, out: np.multiply(x, scale, out=out), time, empty)
        if opts.rate is not None:
            opts.notes.append(f"{label} timestamps taken from {part.time_label} of {source}; "
                              "the given rate is not used")
        elif part.stated_rate is not None:
            _compare_rate(t, part, opts.notes)
    elif rate is not None:
        t = elementwise(lambda i, out: np.divide(i, rate, out=out),
                        _Counter(n), empty)  # = np.arange(n, dtype=np.float64) / rate
        if opts.rate is None:
            opts.notes.append(f"timestamps from the rate {rate:g} Hz{rate_from}")
    elif opts.number_samples:
        t = elementwise(lambda i, out: np.copyto(out, i), _Counter(n), empty)
        opts.notes.append(NUMBERED_NOTE)  # once for both sensors (notes are deduplicated)
    else:
        why = f" ({part.counter_label} is a sample counter, not time)" if part.counter_label else ""
        raise ImucalError(f"{label}: no time column{why}; a sample rate is needed (--rate HZ)",
                          source=source, field="rate")
    _check_timestamps(t, label, source)
    values, t = _bridge_gaps(values, t, label, source, opts.notes)
    return values, t


class _Counter:
    """The sample numbers 0 .. n - 1 as float64, read a slice at a time (``np.arange``'s
    values: integers are exact)."""

    def __init__(self, n: int) -> None:
        self.shape = (n,)

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, key: slice) -> np.ndarray:
        lo, hi, _ = key.indices(self.shape[0])
        return np.arange(lo, hi, dtype=np.float64)


def _rate(part: Part, opts: LoadOptions) -> tuple[float | None, str]:
    """The rate to use where there is no time column, and where it comes from (for notes)."""
    stated = part.stated_rate
    if opts.rate is not None:
        if stated is not None and abs(stated[0] / opts.rate - 1) > RATE_TOLERANCE:
            opts.notes.append(f"{part.source} states {stated[0]:g} Hz ({stated[1]}) but "
                              f"--rate {opts.rate:g} was given; using {opts.rate:g} Hz")
        return opts.rate, ""
    if stated is not None:
        return stated[0], f" stated by {part.source}, {stated[1]}"
    return None, ""


def _compare_rate(t: np.ndarray, part: Part, notes: list[str]) -> None:
    """A rate the preamble states against the time column's (which is used): a note when they
    disagree by more than 1 %."""
    assert part.stated_rate is not None
    stated, where = part.stated_rate
    with np.errstate(over="ignore", invalid="ignore"):
        step = np.diff(t[: min(len(t), 100_001)])
    step = step[np.isfinite(step) & (step > 0)]
    if not len(step):
        return
    measured = 1.0 / float(np.median(step))
    if abs(measured / stated - 1) > RATE_TOLERANCE:
        notes.append(f"{part.source} states {stated:g} Hz ({where}) but its {part.time_label} "
                     f"steps at {measured:.4g} Hz; the time column is used")


def _counts_samples(time: np.ndarray, part: Part, opts: LoadOptions) -> bool:
    """Integers in steps of exactly 1 in a time column that would be read in seconds."""
    if (part.time_unit is not None or part.time_is_datetime or opts.time_unit != "s"
            or time.size < 2 or not chunks_all(time, np.isfinite, 0)):
        return False
    return bool(chunks_all(time, lambda c: np.diff(c) == 1, 1)
                and float(time[0]).is_integer())


def _time_unit(part: Part, opts: LoadOptions) -> str:
    """The user's time_unit, except that a unit named by the file wins over the default "s"."""
    if part.time_is_datetime:
        return "s"
    if part.time_unit is None or part.time_unit == opts.time_unit:
        return opts.time_unit
    if opts.time_unit == "s":
        opts.notes.append(f"{part.time_label} of {part.source} read in {part.time_unit}, "
                          f"{part.time_unit_from}")
        return part.time_unit
    opts.notes.append(f"{part.time_label} of {part.source} looks like {part.time_unit} but "
                      f"time_unit={opts.time_unit} was given; using {opts.time_unit}")
    return opts.time_unit


def _unit_from_steps(time: np.ndarray, part: Part, opts: LoadOptions) -> str:
    """"s", unless that would put the samples more than a second apart: then the first of ms,
    us, ns that gives an IMU's rate (loggers write integer ms or ns timestamps, often since
    boot, under names like "timestamp" that say no unit)."""
    with np.errstate(invalid="ignore", over="ignore"):
        step = np.diff(time[: min(len(time), 100_001)])
    step = step[np.isfinite(step) & (step > 0)]
    if len(step) == 0:
        return "s"
    median = float(np.median(step))
    if median <= 1.0:
        return "s"
    for unit in ("ms", "us", "ns"):
        dt = median * TIME_UNITS[unit]
        if 1.0 / MAX_RATE_HZ <= dt <= 1.0:
            opts.notes.append(f"{part.time_label} of {part.source} read in {unit}: its median "
                              f"step {median:g} means {1.0 / dt:.4g} Hz in {unit}, "
                              f"{1.0 / median:.2g} Hz in seconds (set --time-unit to override)")
            return unit
    return "s"


def _check_timestamps(t: np.ndarray, label: str, source: str, chunk: int = 1 << 18) -> None:
    """Finite, strictly increasing times, or one error naming the first bad index. Read a
    chunk at a time (each chunk's steps start from the last time of the one before): the same
    first bad index and message as ``np.diff`` of the whole, without its copy of the times."""
    for c0 in range(0, len(t), chunk):
        part = t[c0:c0 + chunk]
        finite = np.isfinite(part)
        if not finite.all():
            i = c0 + int(np.flatnonzero(~finite)[0])
            raise ImucalError(f"{label} timestamp at index {i} is {float(t[i])}; expected "
                              "finite, increasing times", source=source, field="time")
    for c0 in range(0, max(len(t) - 1, 0), chunk):
        with np.errstate(over="ignore", invalid="ignore"):
            step = np.diff(t[c0:c0 + chunk + 1])
        bad = np.flatnonzero(~(step > 0))
        if bad.size:
            i = c0 + int(bad[0]) + 1
            kind = "duplicated" if step[i - 1 - c0] == 0 else "not increasing"
            raise ImucalError(f"{label} timestamps {kind} at index {i} ({float(t[i - 1])!r} "
                              f"then {float(t[i])!r}); expected strictly increasing times",
                              source=source, field="time")


def _bridge_gaps(values: np.ndarray, t: np.ndarray, label: str, source: str,
                 notes: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Interpolate short runs of non-finite samples (a dropped packet) and drop short runs at
    either end, where there is nothing to interpolate from; refuse anything more."""
    if chunks_all(values, np.isfinite):  # the usual case: no row mask the length of the signal
        return values, t
    bad = ~np.isfinite(values).all(axis=1)
    n, n_bad = len(values), int(bad.sum())
    step = np.diff(bad.view(np.int8), prepend=np.int8(0), append=np.int8(0))
    starts, ends = np.flatnonzero(step == 1), np.flatnonzero(step == -1)
    lengths = ends - starts
    first = f"{label}: {n_bad} NaN/Inf samples, first at index {int(starts[0])}"
    if lengths.max() > MAX_BRIDGED_RUN:
        j = int(np.argmax(lengths))
        raise ImucalError(f"{first}; the gap of {int(lengths[j])} at index {int(starts[j])} is "
                          f"longer than the {MAX_BRIDGED_RUN} samples that can be bridged",
                          source=source, field="samples")
    # Many short gaps would make the session largely made up: refuse rather than calibrate that.
    if n_bad > max(MAX_BRIDGED_RUN, MAX_BRIDGED_FRACTION * n):
        raise ImucalError(f"{first}; that is {n_bad / n:.1%} of the samples, more than the "
                          f"{MAX_BRIDGED_FRACTION:.0%} that can be bridged", source=source,
                          field="samples")
    head = int(ends[0]) if starts[0] == 0 else 0
    tail = int(starts[-1]) if ends[-1] == n else n
    if tail - head < 2:
        raise ImucalError(f"{first}; fewer than 2 finite samples remain", source=source,
                          field="samples")
    inner = bad.copy()
    inner[:head] = False
    inner[tail:] = False
    if inner.any():
        values = values.copy()
        good = ~bad
        for axis in range(values.shape[1]):
            values[inner, axis] = np.interp(t[inner], t[good], values[good, axis])
        gaps = [(int(a), int(b)) for a, b in zip(starts, ends, strict=True) if head <= a < tail]
        where = ", ".join(f"{a}-{b - 1}" if b - a > 1 else f"{a}" for a, b in gaps[:5])
        where += ", ..." if len(gaps) > 5 else ""
        notes.append(f"{label}: bridged {int(inner.sum())} NaN/Inf samples of {source} by linear "
                     f"interpolation in {plural(len(gaps), 'gap')} (index {where})")
    if head or tail < n:
        ends_named = " and ".join(w for w, hit in (("start", head), ("end", tail < n)) if hit)
        notes.append(f"{label}: dropped {head + n - tail} NaN/Inf samples at the {ends_named} "
                     f"of {source}")
    return values[head:tail], t[head:tail]
