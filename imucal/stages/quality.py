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
    n = len(session.acc)
    after_blocks = (np.linalg.norm(_block_means(cal_acc, det.blocks), axis=1) / g_out - 1) * 1e3
    after_samples = _block_samples_norm_rms(cal_acc, n, g_out, det.blocks)
    before_blocks = before_samples = None
    if session.acc_unit == "counts":
        notes.append("accelerometer in raw counts: no 'before' static norm error without a "
                     "nominal sensitivity")
    else:
        before_blocks = (np.linalg.norm(det.means, axis=1) / g_in - 1) * 1e3
        before_samples = _block_samples_norm_rms(lambda a, b: session.acc[a:b], n, g_in,
                                                 det.blocks)

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


def _block_means(rows: Rows, blocks: np.ndarray) -> np.ndarray:
    """:func:`block_means` of the signal ``rows`` gives, over runs of consecutive blocks of
    about ``RUN_ROWS`` rows (a longer block alone): each block's sum is reduced over its own
    rows as on the whole signal, so the means are the same to the bit."""
    if len(blocks) == 0:
        return np.zeros((0, 3))
    out = []
    i, n_blocks = 0, len(blocks)
    while i < n_blocks:
        j = i + 1 + int(np.searchsorted(blocks[i + 1:, 1], blocks[i, 0] + RUN_ROWS,
                                        side="right"))
        lo, hi = int(blocks[i, 0]), int(blocks[j - 1, 1])
        out.append(block_means(rows(lo, hi), blocks[i:j] - lo))
        i = j
    return np.concatenate(out)


def _block_samples_norm_rms(rows: Rows, n_rows: int, g: float, blocks: np.ndarray,
                            chunk: int = 1 << 16) -> float:
    """RMS over the samples inside the blocks of ``(|x| / g - 1) * 1000`` (mg), ``chunk``
    rows of ``x`` (``rows(lo, hi)``, ``n_rows`` in all) at a time: per-block sums of squares,
    no mask, no temporary the length of ``x``."""
    n = int(np.sum(blocks[:, 1] - blocks[:, 0])) if len(blocks) else 0
    if n == 0:
        return float("nan")
    starts, ends = blocks[:, 0], blocks[:, 1]
    total = 0.0
    for c0 in range(0, n_rows, chunk):
        c1 = min(n_rows, c0 + chunk)
        i0 = int(np.searchsorted(ends, c0, side="right"))  # first block ending after c0
        i1 = int(np.searchsorted(starts, c1, side="left"))  # blocks starting before c1
        if i1 <= i0:
            continue
        dev = _norm_error_mg(rows(c0, c1), g)
        np.multiply(dev, dev, out=dev)
        total += float(np.sum(segment_sums(dev, np.maximum(starts[i0:i1], c0) - c0,
                                           np.minimum(ends[i0:i1], c1) - c0)))
    return float(np.sqrt(total / n))


def _norm_error_mg(x: np.ndarray, g: float) -> np.ndarray:
    """``(|x| / g - 1) * 1000`` per row, in place on one temporary."""
    out = _row_norms(x)
    out *= 1e3 / g
    out -= 1e3
    return out


def _row_norms(x: np.ndarray) -> np.ndarray:
    """Euclidean norm of each row of an (N, 3) array, column by column (the same sums in the
    same order as ``np.linalg.norm(x, axis=1)``, without its slow reduction over short rows)."""
    out = x[:, 0] * x[:, 0]
    for j in range(1, x.shape[1]):
        out += x[:, j] * x[:, j]
    return np.sqrt(out, out=out)
