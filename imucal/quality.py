"""The quality figures a user reads first (method.md §5)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .calibration import CalibratedSignals
from .detect import Detection, block_means

if TYPE_CHECKING:
    from .pipeline import Segment
    from .session import Session


@dataclass(frozen=True)
class Quality:
    """RMS figures before and after; ``None`` where "before" has no meaning (raw counts)."""

    static_norm_rms_mg: tuple[float | None, float]  # block means: the calibration's own error
    sample_norm_rms_mg: tuple[float | None, float]  # single samples: dominated by sensor noise
    gravity_angle_rms_deg: tuple[float | None, float] | None  # None without a gyroscope
    block_norm_error_mg: np.ndarray  # (B,) after, per block
    block_norm_error_before_mg: np.ndarray | None
    notes: tuple[str, ...]


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else float("nan")


def distinct_orientations(vectors: np.ndarray, min_angle_deg: float = 15.0) -> int:
    """How many of the directions differ from all kept ones by at least ``min_angle_deg``.

    A greedy count over blocks (tens to hundreds), not over samples.
    """
    if len(vectors) == 0:
        return 0
    u = vectors / np.linalg.norm(vectors, axis=1, keepdims=True)
    cos_min = np.cos(np.radians(min_angle_deg))
    kept: list[np.ndarray] = []
    for v in u:
        if not kept or np.max(np.array(kept) @ v) < cos_min:
            kept.append(v)
    return len(kept)


def quality_figures(session: Session, det: Detection, cal: CalibratedSignals,
                    segments: list[Segment], g_in: float, g_out: float) -> Quality:
    notes = []
    after_blocks = (np.linalg.norm(block_means(cal.acc, det.blocks), axis=1) / g_out - 1) * 1e3
    mask = _static_mask(len(cal.acc), det.blocks)
    after_samples = (cal.acc_norm[mask] / g_out - 1) * 1e3
    before_blocks = before_samples = None
    if session.acc_unit == "counts":
        notes.append("accelerometer in raw counts: no 'before' static norm error without a "
                     "nominal sensitivity")
    else:
        before_blocks = (np.linalg.norm(det.means, axis=1) / g_in - 1) * 1e3
        before_samples = (np.linalg.norm(session.acc[mask], axis=1) / g_in - 1) * 1e3

    angle = None
    gyro_fits = [s.gyro for s in segments if s.gyro is not None]
    if gyro_fits:
        after = np.concatenate([g.angle_after for g in gyro_fits])
        befores = [g.angle_before for g in gyro_fits]
        before = None
        if all(b is not None for b in befores):
            before = _rms(np.concatenate(befores))
        else:
            notes.append("gyroscope in raw counts with no nominal sensitivity given: no 'before' "
                         "gravity prediction error")
        angle = (before, _rms(after))
    return Quality(
        static_norm_rms_mg=(None if before_blocks is None else _rms(before_blocks),
                            _rms(after_blocks)),
        sample_norm_rms_mg=(None if before_samples is None else _rms(before_samples),
                            _rms(after_samples)),
        gravity_angle_rms_deg=angle, block_norm_error_mg=after_blocks,
        block_norm_error_before_mg=before_blocks, notes=tuple(notes))


def _static_mask(n: int, blocks: np.ndarray) -> np.ndarray:
    """Boolean mask of the samples inside blocks, from a difference array (no loop)."""
    d = np.zeros(n + 1, dtype=np.int32)
    np.add.at(d, blocks[:, 0], 1)
    np.add.at(d, blocks[:, 1], -1)
    return np.cumsum(d[:-1]) > 0
