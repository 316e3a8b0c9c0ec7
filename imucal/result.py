"""What a run produced: the calibration, per-segment fits and every intermediate a reader of
the run (the CLI's summary, the viewer, the calibration file) needs."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from imucal.session import Session
from imucal.settings import Settings
from imucal.stages.accel import AccFit
from imucal.stages.apply import CalibratedSignals, Calibration
from imucal.stages.detect import Detection
from imucal.stages.group import Grouping
from imucal.stages.gyro import GyroFit
from imucal.stages.quality import Quality


@dataclass(frozen=True)
class Segment:
    index: int
    blocks: tuple[int, int]  # [first, last + 1) block indices
    t_start: float  # start of its first still block, s
    t_end: float  # end of its last still block, s
    acc: AccFit
    gyro: GyroFit | None
    orientations: int  # distinct still orientations (15 degrees apart)


@dataclass(frozen=True)
class Result:
    """Everything a run produced: the calibration and every intermediate the viewer shows."""

    session: Session
    settings: Settings
    detection: Detection
    block_times: np.ndarray  # (B, 2) [t_start, t_end) of each static block, s
    whole: AccFit  # the first whole-session accelerometer fit (used for grouping)
    grouping: Grouping
    segments: list[Segment]
    calibration: Calibration
    calibrated: CalibratedSignals
    quality: Quality
    g_in: float
    warnings: list[str] = field(default_factory=list)

    def apply(self, session: Session) -> CalibratedSignals:
        return self.calibration.apply(session)
