"""Input sanity: the faults that give a wrong calibration with no word unless someone looks for
them (issue 11, item 5). Each is found in the signal itself and named where it happens.

- Wrap-around of raw counts: an integer register (int16, a 12-bit ADC...) that overflows jumps by
  2^n between two samples. Unwrapped when unambiguous, else refused.
- Time gaps: a step of the time column far longer than the usual one. A still block must not
  span it (the device may have moved meanwhile) and a turn integrated across it (M5) means
  nothing, so it is left out of the gyroscope fit.
- Partial gyroscope coverage: still blocks and turns outside the gyroscope's samples. The turns
  are left out of the gyroscope fit and of the gravity prediction error (method.md §5), as
  turns through saturated samples are (:mod:`imucal.stages.saturation`).
- Two files of different lengths read at one rate (checked by the loader, the only one to know
  that the timestamps come from ``--rate``).

Warning codes: ``acc_wraparound``, ``gyro_wraparound``, ``time_gap``, ``gyro_no_data``,
``lengths_differ``. Everything is vectorised: a few passes over the signal, no loop over samples.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from imucal.errors import ImucalError, plural
from imucal.numerics.order_stats import ranked_values
from imucal.numerics.rows import search_sorted, value_at
from imucal.numerics.windows import block_means
from imucal.session import (
    MEDIAN_SAMPLE,
    MEDIAN_SMALL,
    Session,
    chunks_all,
    diff_chunks,
    median_step,
)
from imucal.stages.detect import Detection
from imucal.warning import RunWarning

AXES = "xyz"
# A wrap-around is a step of 2^n counts (n >= WRAP_MIN_BITS) across at least half the signal's
# range, at least WRAP_FACTOR times the signal's own 99th-percentile step, and within WRAP_TOL of
# those steps of the power of two (what the signal really moved across the wrap). On the Xsens
# recording (raw 16-bit counts spanning nearly the whole register) the largest step is 6 times
# the 99th percentile and a seventh of the range: no false alarm; read as int16 it wraps 1000s of
# times at rest (its zero is 32768), once at a step that really moved 6680 counts (4.6 steps).
WRAP_FACTOR = 16.0
WRAP_TOL = 8.0
WRAP_MIN_BITS = 8
# A time step this many times the 99th-percentile step is a gap (on a steady clock: 9 or more
# samples missing); short drops (up to 5 NaN samples) are bridged by the loader. The percentile,
# not the median: a logger that stamps samples in batches has a regular long step that is no
# gap. The real recordings' largest step is 1.04 times their median.
GAP_FACTOR = 10.0
# Two files read at one rate may differ in length by this share of the longer one (a logger
# stopped a moment later) with a warning; beyond it the pairing is refused (see one_rate_pairing).
MAX_LENGTH_MISMATCH = 0.01
LENGTHS_NOTE = "files of different length at one rate"


def sensor_files(session: Session) -> tuple[str, str]:
    """The file of the accelerometer and of the gyroscope (the loader names a two-file session
    ``acc + gyro``)."""
    acc, _, gyro = session.source.partition(" + ")
    return acc, gyro or acc


# --- wrap-around -------------------------------------------------------------------------------


def unwrap_session(session: Session) -> tuple[Session, list[RunWarning]]:
    """The session with wrapped raw counts unwrapped, and a warning per sensor saying where;
    an :class:`ImucalError` naming the sample where a wrap cannot be told from a real jump."""
    acc_file, gyro_file = sensor_files(session)
    warnings, changes = [], {}
    for name, label, file, x, t in (("acc", "accelerometer", acc_file, session.acc, session.t_acc),
                                    ("gyro", "gyroscope", gyro_file, session.gyro,
                                     session.t_gyro)):
        if x is None or len(x) < 3 or not chunks_all(x, lambda c: c == np.rint(c)):
            continue  # only integer-valued raw counts can wrap
        fixed, where = x, []
        steps = _largest_steps(x)
        for axis in range(x.shape[1]):
            if steps[axis] < 2.0 ** (WRAP_MIN_BITS - 0.5):
                continue  # no step rounds to a register of WRAP_MIN_BITS bits: no wrap
            offset = _axis_offset(x[:, axis], t, f"{label} {AXES[axis]}", file)
            if offset is None:
                continue
            if fixed is x:
                fixed = np.array(x, dtype=np.float64)
            fixed[:, axis] += offset[0]
            where.append(offset[1])
        if where:
            changes[name] = fixed
            warnings.append(RunWarning(f"{name}_wraparound", f"{label} in {file}: raw counts "
                                       f"wrapped around and were unwrapped: {'; '.join(where)}"))
    return (dataclasses.replace(session, **changes) if changes else session), warnings


def _largest_steps(x: np.ndarray, rows: int = 1 << 16) -> np.ndarray:
    """Each axis's largest ``|x[i + 1] - x[i]|``, a chunk of rows at a time. A wrap is a step
    whose ``rint(log2)`` is at least WRAP_MIN_BITS (:func:`_axis_offset`): an axis whose
    largest step is below ``2^(WRAP_MIN_BITS - 1/2)`` cannot wrap, and is spared the
    whole-signal quantiles (a 1 kHz recording's steps are mostly far smaller)."""
    out = np.zeros(x.shape[1])
    for lo in range(0, max(len(x) - 1, 1), rows):
        with np.errstate(over="ignore", invalid="ignore"):  # absurd values: the full check
            d = np.abs(np.diff(x[lo:lo + rows + 1], axis=0))
        if len(d):
            np.maximum(out, d.max(axis=0), out=out)
    return out


def _axis_offset(x: np.ndarray, t: np.ndarray, what: str, file: str
                 ) -> tuple[np.ndarray, str] | None:
    """The correction that unwraps one axis, with where it applies; None if it never wraps."""
    with np.errstate(over="ignore", invalid="ignore"):  # absurd values: no wrap, no warning
        d = np.diff(x)
        lo, hi = np.quantile(x, [0.001, 0.999])  # the range, blind to a few absurd samples
        span = float(hi - lo)
    a = np.abs(d)
    # The signal's own rate of change: its steps of less than a quarter of its range (a wrap
    # crosses most of it, so frequent wraps cannot pass for the usual step).
    small = a[a < span / 4]
    step = max(float(np.quantile(small, 0.99)) if len(small) else 0.0, 1.0)
    bits = np.minimum(np.rint(np.log2(np.maximum(a, 1.0))), 62.0)  # no register is wider
    width = 2.0 ** bits
    wrap = ((a >= span / 2) & (bits >= WRAP_MIN_BITS) & (a >= WRAP_FACTOR * step)
            & (np.abs(a - width) <= WRAP_TOL * step))
    idx = np.flatnonzero(wrap)
    if idx.size == 0:
        return None  # large jumps that are no power of two are not wraps (a knock, a glitch)

    def refuse(i: int, why: str) -> ImucalError:
        return ImucalError(f"a step of {d[i]:+.0f} counts at sample {i + 1} (t = {t[i + 1]:.3f} "
                           f"s) {why}: cannot tell a wrap-around from a real jump; fix the "
                           "recording's integer width (read it as a wider or unsigned type)",
                           source=file, field=what)

    widths = np.unique(width[idx])
    if len(widths) > 1:  # wraps of 2^15 and 2^16 in one signal: no one register
        i = int(idx[np.flatnonzero(width[idx] != widths[0])[0]])
        raise refuse(i, f"beside wrap-arounds of {widths[0]:.0f}: two register widths")
    W = float(widths[0])
    odd = np.flatnonzero((a > W / 2) & ~wrap)  # more than half the register, and not a wrap
    if odd.size:
        raise refuse(int(odd[0]), f"is more than half of the {W:.0f}-count register that "
                     f"wraps elsewhere (first at sample {idx[0] + 1})")
    jumps = np.zeros(len(x))
    jumps[idx + 1] = -np.sign(d[idx]) * W
    offset = np.cumsum(jumps)
    # Where the recording starts wrapped, the whole offset is one register off: keep the shift
    # that puts the most samples inside the range the raw values occupy.
    lo, hi = float(x.min()), float(x.max())
    shifts = W * np.arange(-1, 2)
    inside = [np.count_nonzero((x + offset + s >= lo) & (x + offset + s <= hi)) for s in shifts]
    offset += shifts[int(np.argmax(inside))]
    if np.abs(offset).max() > W:
        i = int(idx[np.argmax(np.abs(offset[idx + 1]))])
        raise refuse(i, f"takes the signal beyond twice its {W:.0f}-count register")
    n_bad = int(np.count_nonzero(offset))
    first = int(np.flatnonzero(offset)[0]) if n_bad else int(idx[0]) + 1
    return offset, (f"{what}: {plural(len(idx), 'wrap')} of {W:.0f} counts "
                    f"(2^{int(np.log2(W))}), {n_bad} samples corrected, first at sample {first} "
                    f"(t = {t[first]:.3f} s)")


# --- time gaps ---------------------------------------------------------------------------------


def time_gaps(t) -> np.ndarray:
    """Indices ``i`` where ``t[i + 1] - t[i]`` is a gap (GAP_FACTOR times the 99th-percentile
    step), ``t`` read a block at a time: its smallest and largest step first (a steady clock,
    whose largest step is not GAP_FACTOR times its smallest, has no gap, since the percentile
    is at least the smallest step), else numpy's percentile found exactly
    (:func:`_step_quantile`) and the steps beyond it."""
    if t is None or len(t) < 3:
        return np.zeros(0, np.int64)
    ranges = [(0, len(t))]
    steps = diff_chunks(t, ranges)
    lo, hi = np.inf, -np.inf
    for d in steps():
        lo, hi = np.minimum(lo, d.min()), np.maximum(hi, d.max())
    if not hi > GAP_FACTOR * lo:  # (a NaN step: numpy's percentile is NaN, no gap either)
        return np.zeros(0, np.int64)
    limit = GAP_FACTOR * _step_quantile(steps, len(t) - 1, 0.99)
    found, p = [np.zeros(0, np.int64)], 0
    for d in steps():
        found.append(np.flatnonzero(d > limit) + p)
        p += len(d)
    return np.concatenate(found)


def _step_quantile(steps, n: int, q: float) -> float:
    """``np.quantile`` of the ``n`` steps ``steps()`` yields, to the bit: its two order
    statistics (:func:`imucal.numerics.order_stats.ranked_values`; a copy below MEDIAN_SMALL
    steps or where the bracket misses), interpolated as numpy does (index ``(n - 1) q``,
    ``a + (b - a) g``, from ``b`` when ``g >= 0.5``)."""
    v = (n - 1) * float(q)
    prev = int(np.floor(v))
    got = None
    if n >= MEDIAN_SMALL:
        got = ranked_values(steps, n, [[min(prev, n - 1), min(prev + 1, n - 1)]], MEDIAN_SAMPLE)
    if got is None:
        return float(np.quantile(np.concatenate(list(steps())), q))
    a, b = got[0]
    if v >= n - 1:  # numpy takes the largest value for both
        a = b
    g = v - np.floor(v)
    diff = b - a
    return float(b - diff * (1 - g) if g >= 0.5 else a + diff * g)


def gap_warnings(session: Session) -> list[RunWarning]:
    """A warning naming each sensor's gaps (one for a time column the two share)."""
    acc_file, gyro_file = sensor_files(session)
    ga = time_gaps(session.t_acc)
    gg = time_gaps(session.t_gyro) if session.has_gyro else np.zeros(0, np.int64)
    shared = (session.has_gyro and len(ga) == len(gg) and len(ga) > 0
              and np.allclose(session.t_acc[ga], session.t_gyro[gg]))
    out = []
    for label, file, t, gaps in (("accelerometer", acc_file, session.t_acc, ga),
                                 ("gyroscope", gyro_file, session.t_gyro, gg)):
        if not len(gaps) or (shared and label == "gyroscope"):
            continue
        who = "accelerometer and gyroscope" if shared else label
        listed = ", ".join(f"{t[i + 1] - t[i]:.3g} s after sample {i} (t = {t[i]:.3f} to "
                           f"{t[i + 1]:.3f} s)" for i in gaps[:5])
        more = f" and {len(gaps) - 5} more" if len(gaps) > 5 else ""
        out.append(RunWarning("time_gap", f"the {who} time in {file} has "
                              f"{plural(len(gaps), 'gap')}: {listed}{more}; no still block spans "
                              "a gap and turns across one are left out of the gyroscope fit"))
    return out


def split_at_gaps(det: Detection, acc, t) -> Detection:
    """Still blocks cut at the accelerometer's time gaps (the device may have moved while
    nothing was recorded); a piece shorter than the detector's minimum block is dropped. The
    signals are read a block of rows at a time (:func:`time_gaps`, :func:`block_means`)."""
    gaps = time_gaps(t) + 1  # a gap lies just before these samples
    if not len(gaps) or not len(det.blocks):
        return det
    edges = np.unique(np.concatenate([det.blocks.ravel(), gaps]))
    pieces = np.column_stack([edges[:-1], edges[1:]])
    # Keep the pieces inside a block: their start lies in one.
    k = np.searchsorted(det.blocks[:, 0], pieces[:, 0], side="right") - 1
    inside = (k >= 0) & (pieces[:, 1] <= det.blocks[np.maximum(k, 0), 1])
    blocks = pieces[inside & (pieces[:, 1] - pieces[:, 0] >= det.min_len)]
    if np.array_equal(blocks, det.blocks):
        return det
    return dataclasses.replace(det, blocks=blocks, means=block_means(acc, blocks))


# --- gyroscope coverage ------------------------------------------------------------------------


def turns_without_gyro(t_gyro: np.ndarray, block_times: np.ndarray,
                       step: float | None = None) -> np.ndarray:
    """(B-1,) bool: the turn between still blocks k and k+1 is not fully covered by gyroscope
    samples (it starts before the first, ends after the last or crosses a gap). ``step``: the
    clock's median step where known (``Session.gyro_step``), else found here."""
    a, b = block_times[:-1, 1], block_times[1:, 0]
    if step is None:  # np.median(np.diff(t_gyro)), in blocks
        step = median_step(t_gyro, [(0, len(t_gyro))])
    outside = (a < value_at(t_gyro, 0) - step) | (b > value_at(t_gyro, -1) + step)
    gaps = time_gaps(t_gyro)
    g0, g1 = t_gyro[gaps], t_gyro[gaps + 1]
    # gaps that start before the turn ends, minus those that end before it starts
    crossing = np.searchsorted(g0, b, side="left") - np.searchsorted(g1, a, side="right")
    return outside | (crossing > 0)


def blocks_without_gyro(t_gyro: np.ndarray, block_times: np.ndarray) -> np.ndarray:
    """(B,) bool: fewer than two gyroscope samples inside the still block."""
    lo = search_sorted(t_gyro, block_times[:, 0], side="left")
    hi = search_sorted(t_gyro, block_times[:, 1], side="right")
    return (hi - lo) < 2


def coverage_warning(session: Session, block_times: np.ndarray) -> RunWarning | None:
    """Which still blocks and turns have no gyroscope data, or None when all have."""
    no_block = blocks_without_gyro(session.t_gyro, block_times)
    no_turn = turns_without_gyro(session.t_gyro, block_times, session.gyro_step)
    if not no_block.any() and not no_turn.any():
        return None
    tg, ta = session.t_gyro, session.t_acc
    missing = []
    if no_block.any():
        missing.append(f"still {_ranges(no_block, 'block')} (of {len(no_block)})")
    if no_turn.any():
        missing.append(f"{_ranges(no_turn, 'turn')} (of {len(no_turn)}; turn k goes from "
                       "block k to k+1)")
    return RunWarning("gyro_no_data", f"the gyroscope ({sensor_files(session)[1]}: t = "
                      f"{value_at(tg, 0):.2f}-{value_at(tg, -1):.2f} s; the accelerometer: t = "
                      f"{value_at(ta, 0):.2f}-{value_at(ta, -1):.2f} s) has no data (outside its "
                      "span or across a time gap) for "
                      f"{' and '.join(missing)}; turns without "
                      "gyroscope data are left out of the gyroscope fit and of the gravity "
                      "prediction error")


def _ranges(mask: np.ndarray, noun: str, limit: int = 8) -> str:
    """``"blocks 3, 7-12"``: the True indices of a mask as ranges."""
    idx = np.flatnonzero(mask)
    breaks = np.flatnonzero(np.diff(idx) > 1)
    starts = np.r_[idx[0], idx[breaks + 1]]
    ends = np.r_[idx[breaks], idx[-1]]
    parts = [f"{s}" if s == e else f"{s}-{e}" for s, e in zip(starts[:limit], ends[:limit])]
    more = ", ..." if len(starts) > limit else ""
    return f"{noun}{'' if len(idx) == 1 else 's'} {', '.join(parts)}{more}"


# --- two files at one rate ---------------------------------------------------------------------


def one_rate_pairing(t_acc: np.ndarray, t_gyro: np.ndarray, rate: float, acc_file: str,
                     gyro_file: str) -> str | None:
    """Two files timed by one ``--rate`` are paired sample by sample from their first samples;
    a note when their lengths differ, an :class:`ImucalError` when they differ too much.

    Nothing in such files tells an early stop from a late start or from two rates. A logger
    that stopped a moment after the other leaves a tail of under 1 % (handled as data the other
    sensor lacks); beyond that a late start, or two rates (ST parts run at 104 or 952 Hz against
    a nominal 100 or 1000: 4-5 %), are as likely, and either misplaces every later turn against
    the still poses by seconds: that pairing is refused, not guessed.
    """
    n_a, n_g = len(t_acc), len(t_gyro)
    timed_by_rate = all(len(t) > 1 and t[0] == 0.0 and np.isclose(t[-1], (len(t) - 1) / rate,
                                                                  rtol=1e-12, atol=0.0)
                        for t in (t_acc, t_gyro))
    if n_a == n_g or not timed_by_rate:
        return None
    what = (f"{acc_file} has {n_a} samples ({n_a / rate:.2f} s) and {gyro_file} {n_g} "
            f"({n_g / rate:.2f} s) at --rate {rate:g} Hz")
    short = abs(n_a - n_g) / max(n_a, n_g)
    if short > MAX_LENGTH_MISMATCH:
        raise ImucalError(f"{LENGTHS_NOTE}: {what}, {short:.1%} apart: a late start or two "
                          f"different rates cannot be told from an early stop, and either "
                          f"misplaces the turns; give each file a time column, or cut them to "
                          f"the same span", source=f"{acc_file} + {gyro_file}", field="rate")
    return (f"{LENGTHS_NOTE}: {what}; paired from their first samples, the last "
            f"{abs(n_a - n_g) / rate:.2f} s of the longer have no partner")


def input_warning(note: str) -> RunWarning:
    """A loader's note as a warning: its own code where it is one of these checks'."""
    return RunWarning("lengths_differ" if note.startswith(LENGTHS_NOTE) else "input", note)
