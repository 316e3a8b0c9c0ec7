"""What a run produced: the calibration, per-segment fits and every intermediate a reader of
the run (the CLI's summary, the viewer, the calibration file) needs."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from imucal.numerics.windows import mask_of_runs, samples_within
from imucal.session import Session
from imucal.settings import Settings
from imucal.stages.accel import AccFit
from imucal.stages.accel_cv import AccCrossValidation
from imucal.stages.apply import CalibratedSignals, Calibration
from imucal.stages.detect import Detection
from imucal.stages.group import Grouping
from imucal.stages.gyro import GyroFit
from imucal.stages.quality import Quality
from imucal.warning import RunWarning


@dataclass(frozen=True)
class Segment:
    index: int
    blocks: tuple[int, int]  # [first, last + 1) block indices
    t_start: float  # start of its first still block, s
    t_end: float  # end of its last still block, s
    acc: AccFit
    gyro: GyroFit | None
    orientations: int  # distinct still orientations (15 degrees apart)
    acc_cv: AccCrossValidation  # each still block predicted by the fit without it (§5)

    @property
    def n_blocks(self) -> int:
        return self.blocks[1] - self.blocks[0]


@dataclass(frozen=True)
class Result:
    """Everything a run produced: the calibration and every intermediate the viewer shows.

    The still blocks have one convention throughout: ``detection.blocks`` are accelerometer
    sample ranges ``[start, end)``; ``block_times`` the times of their first and last sample;
    on the gyroscope's clock a block holds the samples inside ``[t_start, t_end]``, ends
    included (:attr:`gyro_blocks`, the samples the gyroscope bias is measured on).
    """

    session: Session
    settings: Settings
    detection: Detection
    block_times: np.ndarray  # (B, 2) [t_start, t_end]: first and last still sample's time, s
    whole: AccFit  # the first whole-session accelerometer fit (used for grouping)
    grouping: Grouping
    segments: list[Segment]
    calibration: Calibration
    calibrated: CalibratedSignals
    quality: Quality
    g_in: float
    warnings: list[RunWarning] = field(default_factory=list)

    def apply(self, session: Session) -> CalibratedSignals:
        return self.calibration.apply(session)

    # --- derived arrays: computed on request (the CLI never needs them, the viewer does) ---

    @property
    def block_middles(self) -> np.ndarray:
        """(B,) the middle of each still block, s."""
        return self.block_times.mean(axis=1)

    @property
    def acc_still(self) -> np.ndarray:
        """(N,) True on the accelerometer samples inside a still block."""
        return mask_of_runs(self.detection.blocks, len(self.session.t_acc))

    @property
    def gyro_blocks(self) -> np.ndarray | None:
        """(B, 2) ``[start, end)`` gyroscope sample ranges of the still blocks (None without a
        gyroscope): the samples inside ``[t_start, t_end]``, the same as the accelerometer's
        blocks when both share one clock."""
        if not self.session.has_gyro:
            return None
        return samples_within(self.session.t_gyro, self.block_times)

    @property
    def gyro_still(self) -> np.ndarray | None:
        """(M,) True on the gyroscope samples inside a still block (None without a gyroscope)."""
        blocks = self.gyro_blocks
        return None if blocks is None else mask_of_runs(blocks, len(self.session.t_gyro))

    @property
    def raw_acc_norm(self) -> np.ndarray:
        """(N,) ``|a_raw|`` in the calibrated unit through the whole-session fit's nominal frame:
        the uncalibrated magnitude beside ``calibrated.acc_norm``."""
        return self.whole.nominal_norm(self.session.acc)

    @property
    def raw_gyro_norm(self) -> np.ndarray | None:
        """(M,) ``|w_raw|`` in nominal rad/s (first segment's nominal, see
        :meth:`GyroFit.nominal_rate`) beside ``calibrated.gyro_norm``; None without a fit."""
        s, fit = self.session, self.segments[0].gyro
        if not s.has_gyro or fit is None:
            return None
        return np.linalg.norm(fit.nominal_rate(s.gyro, s.gyro_unit), axis=1)
