"""What a run produced: the calibration, per-segment fits and every intermediate a reader of
the run (the CLI's summary, the viewer, the calibration file) needs."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from imucal.numerics.windows import mask_of_runs, samples_within
from imucal.session import Session
from imucal.settings import Settings
from imucal.stages.accel import AccFit
from imucal.stages.accel_cv import AccCrossValidation
from imucal.stages.apply import CalibratedSignals, Calibration
from imucal.stages.detect import Detection
from imucal.stages.group import Grouping
from imucal.stages.guide import Guide
from imucal.stages.gyro import GyroFit
from imucal.stages.noise import NoiseReport, still_noise
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
    quality: Quality
    g_in: float
    warnings: list[RunWarning] = field(default_factory=list)
    guide: Guide | None = None  # poses, holds and turns against the limits; what to record

    def apply(self, session: Session) -> CalibratedSignals:
        return self.calibration.apply(session)

    @cached_property
    def calibrated(self) -> CalibratedSignals:
        """The session's calibrated signals, whole (M2, M4): made on the first request and
        kept. The run itself never needs them whole (at 6 h and 1 kHz they are 1 GB): its
        figures and the noise read them a block or a chunk at a time; ``--calibrated``, the
        viewer and the exports ask for them."""
        return self.calibration.apply(self.session)

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

    @cached_property
    def noise(self) -> NoiseReport | None:
        """The sensor's noise measured on the calibrated still blocks (white noise density and
        bias instability per axis, method of :mod:`imucal.stages.noise`); None when the blocks
        are too short. Computed once, on request: the calibration file and the viewer read it,
        a script that only wants the parameters never pays for it. Unless the calibrated
        signals were made already, it reads only the still samples, one sensor at a time."""
        if "calibrated" in self.__dict__ or len(self.session.t_acc) < 2:
            return still_noise(self.calibrated, self.block_times)
        still = StillSignals(self.calibration, self.session, self.block_times)
        if len(still.t_acc) < 2:  # still_noise says None on the signal's length, not the blocks'
            return still_noise(self.calibrated, self.block_times)
        return still_noise(still, self.block_times)  # type: ignore[arg-type]

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


RUN_ROWS = 1 << 18  # rows of signal calibrated at once while packing the still samples


class StillSignals:
    """The calibrated signals' samples inside the still blocks ``[t_start, t_end)`` (the ranges
    :func:`imucal.stages.noise.still_noise` reads), packed end to end, in place of
    :class:`CalibratedSignals` for the noise: the blocks lie at the same places of the packed
    time arrays, so the figures are the same to the bit. Each signal is made on access and not
    kept: the noise holds one sensor's still samples at a time, not both whole signals."""

    def __init__(self, calibration: Calibration, session: Session, block_times: np.ndarray):
        self.calibration, self.session = calibration, session
        self.block_times = np.asarray(block_times, dtype=float).reshape(-1, 2)
        self.acc_unit = calibration.acc_unit

    def _ranges(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        lo = np.searchsorted(t, self.block_times[:, 0], side="left")
        return lo, np.maximum(np.searchsorted(t, self.block_times[:, 1], side="left"), lo)

    def _packed(self, t: np.ndarray, rows, width: int | None) -> np.ndarray:
        """Rows ``rows(lo, hi)`` of each block's range, end to end, a run of blocks of about
        ``RUN_ROWS`` rows at a time (one array of the still samples, one run's rows)."""
        lo, hi = self._ranges(t)
        out = np.empty((int(np.sum(hi - lo)),) + (() if width is None else (width,)))
        i, p = 0, 0
        while i < len(lo):
            j = i + 1 + int(np.searchsorted(hi[i + 1:], lo[i] + RUN_ROWS, side="right"))
            r0, r1 = int(lo[i]), int(hi[j - 1])
            x = rows(r0, r1)
            for a, b in zip(lo[i:j], hi[i:j]):
                out[p:p + b - a] = x[a - r0:b - r0]
                p += b - a
            i = j
        return out

    @property
    def t_acc(self) -> np.ndarray:
        return self._packed(self.session.t_acc, lambda a, b: self.session.t_acc[a:b], None)

    @property
    def acc(self) -> np.ndarray:
        return self._packed(self.session.t_acc,
                            lambda a, b: self.calibration.rows(self.session, "acc", a, b), 3)

    @property
    def t_gyro(self) -> np.ndarray | None:
        t = self.session.t_gyro
        return None if t is None else self._packed(t, lambda a, b: t[a:b], None)

    @property
    def gyro(self) -> np.ndarray | None:
        if not self.calibration.applies_gyro(self.session):
            return None
        return self._packed(self.session.t_gyro,
                            lambda a, b: self.calibration.rows(self.session, "gyro", a, b), 3)
