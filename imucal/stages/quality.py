"""The quality figures a user reads first (method.md §5)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from imucal.numerics.windows import block_means, segment_sums
from imucal.stages.detect import Detection

# Rows [lo, hi) of a signal: the raw array sliced, or the calibrated one computed on request
# (:meth:`imucal.stages.apply.Calibration.rows`), so the figures never need it whole.
Rows = Callable[[int, int], np.ndarray]
RUN_ROWS = 1 << 18  # rows of signal per run of blocks averaged at once

if TYPE_CHECKING:
    from imucal.session import Session
    from imucal.stages.gyro import GyroFit


@dataclass(frozen=True)
class BeforeAfter:
    """One figure with the raw sensor (through its nominal frame) and with the calibration."""

    before: float | None  # None where it has no meaning (raw counts without a nominal)
    after: float


@dataclass(frozen=True)
class Quality:
    """The RMS figures of method.md §5, before and after."""

    static_norm_rms_mg: BeforeAfter  # block means: the calibration's own error
    sample_norm_rms_mg: BeforeAfter  # single samples: dominated by sensor noise
    gravity_angle_rms_deg: BeforeAfter | None  # None without a gyroscope
    # The same two figures out of sample (method.md §5): each still block, and each turn,
    # predicted by a fit that did not see it. NaN where too few blocks or turns to hold out.
    static_norm_cv_mg: float
    gravity_angle_cv_deg: float | None  # None without a gyroscope
    block_norm_error_mg: np.ndarray  # (B,) after, per block
    block_norm_error_before_mg: np.ndarray | None
    notes: tuple[str, ...]


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else float("nan")


def quality_figures(session: Session, det: Detection, cal_acc: Rows,
                    gyro_fits: list[GyroFit], held_out_mg: np.ndarray, g_in: float,
                    g_out: float) -> Quality:
    """The figures of method.md §5; ``cal_acc(lo, hi)`` the calibrated accelerometer's rows
    (read a run of blocks or a chunk at a time), ``held_out_mg`` (B,) each still block's norm
    error predicted by the accelerometer fit without it (:mod:`imucal.stages.accel_cv`)."""
    notes = []
    means, after_samples = _block_figures(cal_acc, det.blocks, g_out, means=True)
    after_blocks = (np.linalg.norm(means, axis=1) / g_out - 1) * 1e3
    before_blocks = before_samples = None
    if session.acc_unit == "counts":
        notes.append("accelerometer in raw counts: no 'before' static norm error without a "
                     "nominal sensitivity")
    else:
        before_blocks = (np.linalg.norm(det.means, axis=1) / g_in - 1) * 1e3
        before_samples = _block_figures(lambda a, b: session.acc[a:b], det.blocks, g_in,
                                        means=False)[1]

    angle = angle_cv = None
    if gyro_fits:
        # Transitions through saturated samples are predicted wrong by any calibration:
        # they are left out of the fit and of its figure (and shown in the recording).
        after = np.concatenate([g.angle_after[~g.excluded] for g in gyro_fits])
        befores = [None if g.angle_before is None else g.angle_before[~g.excluded]
                   for g in gyro_fits]
        before = None
        if all(b is not None for b in befores):
            before = _rms(np.concatenate(befores))
        else:
            notes.append("gyroscope in raw counts with no nominal sensitivity given: no 'before' "
                         "gravity prediction error")
        angle = BeforeAfter(before, _rms(after))
        held = np.concatenate([g.cv.angle[~g.excluded] for g in gyro_fits])
        angle_cv = _rms(held) if np.all(np.isfinite(held)) else float("nan")
    return Quality(
        static_norm_rms_mg=BeforeAfter(None if before_blocks is None else _rms(before_blocks),
                                       _rms(after_blocks)),
        sample_norm_rms_mg=BeforeAfter(before_samples, after_samples),
        gravity_angle_rms_deg=angle, static_norm_cv_mg=_rms(held_out_mg),
        gravity_angle_cv_deg=angle_cv, block_norm_error_mg=after_blocks,
        block_norm_error_before_mg=before_blocks, notes=tuple(notes))


def _block_figures(rows: Rows, blocks: np.ndarray, g: float, *, means: bool,
                   chunk: int = 1 << 16) -> tuple[np.ndarray, float]:
    """:func:`block_means` of the signal ``rows(lo, hi)`` gives (if ``means``) and the RMS over
    the samples inside the blocks of ``(|x| / g - 1) * 1000`` (mg), from one read of each run
    of consecutive blocks of about ``RUN_ROWS`` rows (a longer block alone): only the blocks'
    rows are read, once for both figures (the calibrated rows are computed on request).

    The same to the bit as each figure on the whole signal: a block's sum is reduced over its
    own rows; the sum of squares is grouped as a pass over ``chunk``-row chunks of the signal
    groups it (each block's part in each chunk summed over its own rows, the parts of one chunk
    summed together, the chunks added in order), whatever run the parts were read in."""
    if len(blocks) == 0:
        return np.zeros((0, 3)), float("nan")
    out = []
    parts: dict[int, list[np.ndarray]] = {}  # chunk -> its blocks' parts' sums, in order
    i, n_blocks = 0, len(blocks)
    while i < n_blocks:
        j = i + 1 + int(np.searchsorted(blocks[i + 1:, 1], blocks[i, 0] + RUN_ROWS,
                                        side="right"))
        lo, hi = int(blocks[i, 0]), int(blocks[j - 1, 1])
        x = rows(lo, hi)
        if means:
            out.append(block_means(x, blocks[i:j] - lo))
        dev = _norm_error_mg(x, g)
        np.multiply(dev, dev, out=dev)
        # Each block cut at the chunk edges: (chunk, start, end) of every part, in order.
        s, e = blocks[i:j, 0], blocks[i:j, 1]
        c0, c1 = s // chunk, (e - 1) // chunk
        count = c1 - c0 + 1
        first = np.repeat(np.cumsum(count) - count, count)
        ck = np.repeat(c0, count) + np.arange(int(count.sum())) - first
        ps = np.maximum(np.repeat(s, count), ck * chunk)
        pe = np.minimum(np.repeat(e, count), (ck + 1) * chunk)
        sums = segment_sums(dev, ps - lo, pe - lo)
        del x, dev  # not held while the next run is read
        cut = np.flatnonzero(np.diff(ck)) + 1
        for c, v in zip(ck[np.r_[0, cut]].tolist(), np.split(sums, cut)):
            parts.setdefault(c, []).append(v)
        i = j
    total = 0.0
    for c in sorted(parts):
        total += float(np.sum(np.concatenate(parts[c])))
    n = int(np.sum(blocks[:, 1] - blocks[:, 0]))
    return (np.concatenate(out) if means else np.zeros((0, 3))), float(np.sqrt(total / n))


def _norm_error_mg(x: np.ndarray, g: float) -> np.ndarray:
    """``(|x| / g - 1) * 1000`` per row, in place on one temporary."""
    out = row_norms(x)
    out *= 1e3 / g
    out -= 1e3
    return out


def row_norms(x: np.ndarray) -> np.ndarray:
    """Euclidean norm of each row of an (N, 3) array, column by column (the same sums in the
    same order as ``np.linalg.norm(x, axis=1)``, without its slow reduction over short rows)."""
    out = x[:, 0] * x[:, 0]
    for j in range(1, x.shape[1]):
        out += x[:, j] * x[:, j]
    return np.sqrt(out, out=out)
