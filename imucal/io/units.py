"""Units of a recording (method.md §0): their spellings, and the guesses from the values.

One table of spellings serves the arguments (``--acc-unit m/s^2``), the hints in column names
(``acc_x (m/s²)``) and a file's own statements; where none says, the unit is guessed from the
values and the guess is recorded in the session notes.
"""

from __future__ import annotations

import re

import numpy as np

from imucal.errors import ImucalError
from imucal.numerics.order_stats import values_at_ranks

TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9,
              "100us": 1e-4}  # the last only as a name implies it (Xsens SampleTimeFine)


def unit_key(text: str) -> str:
    """'m/s^2' -> 'ms2', 'deg/s' -> 'degs', '°/s' -> 'degs', 'µs' -> 'us'."""
    return re.sub(r"[^a-z0-9]", "", unit_key_spaced(text.strip().lower()))


def unit_key_spaced(text: str) -> str:
    """Like :func:`unit_key` but keeps token boundaries ("acc_x_m/s^2" -> "acc x m s 2")."""
    text = text.replace("°", "deg").replace("²", "2").replace("µ", "u").replace("μ", "u")
    return re.sub(r"[^a-z0-9]+", " ", text)


ACC_UNIT_KEYS = {
    "g": "g", "ms2": "m/s^2", "mss": "m/s^2", "mps2": "m/s^2", "msec2": "m/s^2",
    "counts": "counts", "count": "counts", "raw": "counts", "lsb": "counts", "adc": "counts",
}
GYRO_UNIT_KEYS = {
    "rads": "rad/s", "radpers": "rad/s", "degs": "deg/s", "dps": "deg/s", "degpers": "deg/s",
    "counts": "counts", "count": "counts", "raw": "counts", "lsb": "counts", "adc": "counts",
}
TIME_UNIT_KEYS = {
    "s": "s", "sec": "s", "secs": "s", "second": "s", "seconds": "s",
    "ms": "ms", "msec": "ms", "millis": "ms", "us": "us", "usec": "us", "micros": "us",
    "ns": "ns", "nsec": "ns", "nanos": "ns", "nanosec": "ns",
}
# Units only column names use (ST's "A_X [mg]", "G_X [mdps]"): converted on load, as deg/s is.
SCALED_UNITS = {"mg": ("g", 1e-3), "mdeg/s": ("deg/s", 1e-3)}
ACC_NAME_UNITS = {**ACC_UNIT_KEYS, "mg": "mg", "millig": "mg"}
GYRO_NAME_UNITS = {**GYRO_UNIT_KEYS, "mdps": "mdeg/s", "mdegs": "mdeg/s", "degsec": "deg/s",
                   "radsec": "rad/s"}


def check_choice(value: str, keys: dict[str, str], name: str, source: str) -> str:
    canonical = keys.get(unit_key(value)) if isinstance(value, str) else None
    if canonical is None:
        choices = ", ".join(sorted(set(keys.values())))
        raise ImucalError(f"expected one of {choices}, got {value!r}", source=source, field=name)
    return canonical


def check_unit_arg(value: str, keys: dict[str, str], name: str, source: str) -> str:
    if isinstance(value, str) and value.strip().lower() == "auto":
        return "auto"
    return check_choice(value, {**keys, "auto": "auto"}, name, source)


# --- guesses from the values ---------------------------------------------------------------------


def _integer_like(x: np.ndarray, rows: int = 1 << 16) -> bool:
    """``np.mean(x == np.round(x)) >= 0.99`` a block of rows at a time (no rounded copy of
    ``x``: 500 MB at 6 hours of 1 kHz): numpy's mean of booleans is their exact count over n."""
    # Interpolated gaps are not integers; a few of them must not hide raw counts.
    whole = sum(int(np.count_nonzero(x[lo:lo + rows] == np.round(x[lo:lo + rows])))
                for lo in range(0, len(x), rows))
    return x.size > 0 and whole / x.size >= 0.99


def _row_norms(x: np.ndarray, rows: int = 1 << 16) -> np.ndarray:
    """``np.linalg.norm(x, axis=1)`` a block of rows at a time: no (N, 3) temporary of squares
    (at 6 hours of 1 kHz, 500 MB while loading)."""
    out = np.empty(len(x))
    for lo in range(0, len(x), rows):
        out[lo:lo + rows] = np.linalg.norm(x[lo:lo + rows], axis=1)
    return out


def guess_acc_unit(acc: np.ndarray) -> tuple[str | None, float]:
    """The unit the median norm suggests (1 g, 9.8 m/s^2, or raw counts), and that norm."""
    with np.errstate(over="ignore", invalid="ignore"):
        norm = _median_row_norm(acc)
        if 0.5 <= norm <= 2.0:
            return "g", norm
        if 5.0 <= norm <= 20.0:
            return "m/s^2", norm
        if _abs_median(acc) > 100 or (norm > 50 and _integer_like(acc)):
            return "counts", norm
    return None, norm


def resolve_acc_unit(acc: np.ndarray, unit: str, hint: str | None, source: str,
                     notes: list[str]) -> str:
    """The user's unit, else the one the file names, else the guess; doubts become notes."""
    guess, norm = guess_acc_unit(acc)
    if unit != "auto":
        if guess is not None and guess != unit:
            notes.append(f"acc_unit {unit} given, but the median norm {norm:.4g} looks like "
                         f"{guess}")
        return unit
    if hint is not None:
        doubt = ""
        if guess not in (None, hint):
            doubt = f", though the median norm {norm:.4g} looks like {guess}"
        notes.append(f"accelerometer unit {hint} from the column names{doubt} (set --acc-unit to "
                     "override)")
        return hint
    if guess is None:
        raise ImucalError(
            f"cannot tell the accelerometer unit: median norm {norm:.4g} is not near 1 (g), "
            "9.8 (m/s^2) or raw counts; set --acc-unit", source=source, field="acc_unit",
        )
    notes.append(f"accelerometer unit guessed as {guess} from median norm {norm:.4g} (set "
                 "--acc-unit to override)")
    return guess


def resolve_gyro_unit(gyro: np.ndarray, unit: str, hint: str | None, acc_unit: str,
                      notes: list[str]) -> str:
    """The user's unit, else the one the file names, else a guess from the magnitudes."""
    if unit != "auto":
        return unit
    if hint is not None:
        notes.append(f"gyroscope unit {hint} from the column names (set --gyro-unit to "
                     "override)")
        return hint
    median, p995 = abs_median_p995(gyro)
    if acc_unit == "counts" and median > 100 and _integer_like(gyro):
        guess, why = "counts", f"integer values with median |value| {median:.4g}"
    elif p995 > 20:
        guess, why = "deg/s", f"99.5th percentile of |w| {p995:.4g} (too fast for rad/s)"
    else:
        guess, why = "rad/s", f"99.5th percentile of |w| {p995:.4g}"
    notes.append(f"gyroscope unit guessed as {guess} from {why} (set --gyro-unit to "
                 "override)")
    return guess


# --- exact order statistics of |x| without a copy of x (issue 12: 500 MB at 6 h of 1 kHz) -------

SMALL = 1 << 21  # values: below this, the copy is cheap and np.median / np.percentile do it
ROWS = 1 << 16  # rows of x read at a time
SAMPLE_ROWS = 1 << 18  # rows of x sampled for the brackets (at most one in 16)


def abs_median_p995(x: np.ndarray, small: int = SMALL) -> tuple[float, float]:
    """``np.median(np.abs(x))`` and ``np.percentile(np.abs(x), 99.5)``, the same to the bit,
    without a copy of ``x``: the order statistics they interpolate are found exactly from a
    bracket (a strided sample's quantiles, widened), counting the values below it and keeping
    only those inside it, a block of rows at a time. The interpolation is numpy's (linear:
    index ``(n - 1) q``, ``a + (b - a) t``, from ``b`` when ``t >= 0.5``). A bracket that
    misses (it cannot, but for ties at the edge of a tiny sample) falls back to the copy."""
    n = x.size
    if n < small:
        return _abs_median_p995_copy(x)
    med_ranks = [(n - 1) // 2, n // 2]
    q = np.true_divide(99.5, 100)
    v = (n - 1) * q
    prev = int(np.floor(v))
    pct_ranks = [min(prev, n - 1), min(prev + 1, n - 1)]
    stats = _order_statistics(x, _abs_values, [med_ranks, pct_ranks])
    if stats is None:
        return _abs_median_p995_copy(x)
    (m0, m1), (a, b) = stats
    if np.isnan(m0) or np.isnan(a):
        return float("nan"), float("nan")
    median = float(np.mean(np.array([m0, m1]))) if n % 2 == 0 else float(m1)
    if v >= n - 1:  # numpy takes the largest value for both
        a = b
    t = v - np.floor(v)
    diff = b - a
    p995 = b - diff * (1 - t) if t >= 0.5 else a + diff * t
    return median, float(p995)


def _abs_median(x: np.ndarray, small: int = SMALL) -> float:
    """``np.median(np.abs(x))`` to the bit, without a copy of a long ``x`` (as above)."""
    n = x.size
    stats = None if n < small else _order_statistics(x, _abs_values, [[(n - 1) // 2, n // 2]])
    if stats is None:
        return float(np.median(np.abs(x), overwrite_input=True))
    m0, m1 = stats[0]
    if np.isnan(m0):
        return float("nan")
    return float(np.mean(np.array([m0, m1]))) if n % 2 == 0 else float(m1)


def _abs_median_p995_copy(x: np.ndarray) -> tuple[float, float]:
    magnitude = np.abs(x)  # our own copy: the order statistics may reorder it in place
    median = float(np.median(magnitude, overwrite_input=True))
    p995 = float(np.percentile(magnitude, 99.5, overwrite_input=True))
    return median, p995


def _median_row_norm(x: np.ndarray, small: int = SMALL) -> float:
    """``np.median(np.linalg.norm(x, axis=1))`` to the bit, without the norms of every row
    at once for a long signal (see :func:`abs_median_p995`)."""
    n = len(x)
    if n < small:
        return float(np.median(_row_norms(x), overwrite_input=True))
    stats = _order_statistics(x, _row_norms, [[(n - 1) // 2, n // 2]], _norm_screen)
    if stats is None:
        return float(np.median(_row_norms(x), overwrite_input=True))
    m0, m1 = stats[0]
    if np.isnan(m0):
        return float("nan")
    return float(np.mean(np.array([m0, m1]))) if n % 2 == 0 else float(m1)


def _abs_values(x: np.ndarray) -> np.ndarray:
    return np.abs(x).ravel()


# Relative slack of the screen's sums of squares: theirs and numpy's differ by a few 1e-16
# (three non-negative terms added in another order), so a row this far past a bracket's edge
# is past it in numpy's norms too; edges outside [1e-100, 1e100] are not screened (squares
# there underflow or overflow).
_SLACK = 1e-9
_SCREENED = (1e-100, 1e100)


def _norm_screen(rows: np.ndarray, lo: float, hi: float) -> tuple[int, np.ndarray]:
    """How many of ``rows`` have a norm surely below ``lo``, and the rows that may lie in
    ``[lo, hi]`` (NaN rows among them), from sums of squares taken a column at a time: five
    times cheaper than ``np.linalg.norm(rows, axis=1)``, which then runs on the few rows near
    the bracket only, so every value counted or kept is numpy's own."""
    s = rows[:, 0] * rows[:, 0]
    for j in range(1, rows.shape[1]):
        s += rows[:, j] * rows[:, j]
    below = np.zeros(len(s), dtype=bool)
    if _SCREENED[0] <= lo <= _SCREENED[1]:
        below = s < lo * lo * (1.0 - _SLACK)
    outside = below.copy()
    if _SCREENED[0] <= hi <= _SCREENED[1]:
        outside |= s > hi * hi * (1.0 + _SLACK)
    return int(np.count_nonzero(below)), rows[~outside]


def _order_statistics(x: np.ndarray, values, groups: list[list[int]],
                      screen=None) -> list[list[float]] | None:
    """For each group of ranks (close together), the values of those ranks in the sorted
    ``values(x)`` (a 1-D array row by row: ``values(x[a:b])`` is that of rows a to b; NaN if
    one is NaN, as numpy's are), ``ROWS`` rows at a time; None if a bracket missed.

    A strided sample of rows brackets each group (its quantiles widened by four standard
    deviations of a sample quantile's rank); one pass then counts the values below each
    bracket and keeps those inside it, a value the sample holds counted rather than kept (a
    clock's few steps or tied counts cost nothing). The values at the ranks are those
    ``np.sort`` puts there: numpy's median or percentile interpolated from them is numpy's to
    the bit. ``screen(rows, lo, hi)`` (optional) says cheaply how many rows are surely below
    ``lo`` and which may be inside; ``values`` then runs on those only."""
    n = len(values(x[:1])) * len(x)
    drawn = np.sort(values(x[::max(16, len(x) // SAMPLE_ROWS)]))
    nan = [[float("nan")] * len(r) for r in groups]
    if not len(drawn) or np.isnan(drawn[-1]):
        return nan if len(drawn) else None
    m = len(drawn)
    margin = max(0.004, 4.0 / np.sqrt(m))
    brackets, known = [], []
    for ranks in groups:
        lo = int(np.floor((min(ranks) / n - margin) * m))
        hi = int(np.ceil((max(ranks) / n + margin) * m))
        edges = (drawn[lo] if lo > 0 else -np.inf, drawn[hi] if hi < m else np.inf)
        brackets.append(edges)
        known.append(np.unique(drawn[(drawn >= edges[0]) & (drawn <= edges[1])]))
    del drawn
    counts = [np.zeros(len(k), dtype=np.int64) for k in known]
    below = [0] * len(groups)
    inside: list[list[np.ndarray]] = [[] for _ in groups]
    kept = 0
    for r0 in range(0, len(x), ROWS):
        rows = x[r0:r0 + ROWS]
        c = values(rows) if screen is None else None
        for g, (lo_v, hi_v) in enumerate(brackets):
            if screen is not None:
                sure, near = screen(rows, lo_v, hi_v)
                below[g] += sure
                c = values(near)
            if np.isnan(c).any():
                return nan
            below[g] += int(np.count_nonzero(c < lo_v))
            got = c[(c >= lo_v) & (c <= hi_v)]
            k = known[g]
            if len(k):
                pos = np.minimum(np.searchsorted(k, got), len(k) - 1)
                hit = k[pos] == got
                counts[g] += np.bincount(pos[hit], minlength=len(k))
                got = got[~hit]
            inside[g].append(got)
            kept += len(got)
        if kept > n // 8:  # the brackets hold too much: no saving left
            return None
    out = [values_at_ranks([r - below[g] for r in ranks], known[g], counts[g], inside[g])
           for g, ranks in enumerate(groups)]
    return None if any(p is None for p in out) else out  # type: ignore[return-value]
