"""What a run produced: the calibration, per-segment fits and every intermediate a reader of
the run (the CLI's summary, the viewer, the calibration file) needs."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from imucal.numerics.windows import mask_of_runs, samples_within
from imucal.session import Session
from imucal.settings import Settings
from imucal.stages.accel import AccFit
from imucal.stages.accel_cv import AccCrossValidation
from imucal.stages.apply import CHUNK_ROWS, CalibratedSignals, Calibration, segment_pieces
from imucal.stages.apply_triads import Combination
from imucal.stages.detect import Detection
from imucal.stages.group import Grouping
from imucal.stages.guide import Guide
from imucal.stages.gyro import GyroFit
from imucal.stages.mag import MagFit
from imucal.stages.noise import NoiseReport, still_noise
from imucal.stages.quality import Quality
from imucal.stages.temperature import BiasPolynomial
from imucal.stages.triads import AgainstReference, GyroAgreement, TriadAgreement
from imucal.stages.verdict import Verdict
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

    @property
    def number(self) -> int:
        """The segment as people count it, from 1: the one numbering of every text, warning,
        calib.json entry, viewer label and ``imucal export --segment`` (``index`` is its
        0-based position in :attr:`Result.segments`)."""
        return self.index + 1


@dataclass(frozen=True)
class Triad:
    """Another accelerometer triad of the session (method.md §11): its own run of the whole
    method (``result``: None where it could not be calibrated, ``said`` tells why), with its
    gyroscope where its IMU has one, and its rotation to the reference and agreement with it
    once calibrated (``agreement``: None without enough shared still blocks), and its
    gyroscope's rotation to the reference's from the turns (``gyro_agreement``, M14)."""

    name: str  # the accelerometer stream's name, e.g. "acc sensor_accel:1"
    gyro: str | None  # the gyroscope stream calibrated with it, if any
    result: Result | None
    agreement: TriadAgreement | None
    said: tuple[str, ...] = ()
    gyro_agreement: GyroAgreement | None = None
    # Its M2 and rotation fitted to the reference's calibrated gravity vectors (M15), its
    # output in its own calibrated unit; None without enough shared blocks.
    against_reference: AgainstReference | None = None
    # How far its clock read ahead of the reference's (s, from the motion both saw; its times
    # were moved by it where it exceeded a couple of sample steps); None: not compared.
    clock_offset_s: float | None = None


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
    verdict: Verdict | None = None  # good / usable with caveats / not usable, and why
    # the magnetometer over the whole session (M8, stages/mag.py); None without one, or when
    # it could not be calibrated (the warnings say why)
    magnetometer: MagFit | None = None
    # The session's other triads, each calibrated on its own and put in this run's frame
    # (method.md §11; imucal.pipeline.calibrate_triads); empty for a session of one triad.
    triads: tuple[Triad, ...] = ()
    # Each sensor's bias as a polynomial in temperature (method.md §12;
    # imucal.pipeline.calibrate_temperature); empty unless asked for and a stream is there.
    temperature: tuple[BiasPolynomial, ...] = ()
    # The low-range and high-range accelerometers combined (method.md §11, M18;
    # imucal.pipeline.combine_triads); None unless the run's triads are such a pair.
    combined: Combination | None = None

    def apply(self, session: Session) -> CalibratedSignals:
        return self.calibration.apply(session)

    @cached_property
    def calibrated(self) -> CalibratedSignals:
        """The session's calibrated signals, whole (M2, M4): made on the first request and
        kept. The run itself never needs them whole (at 6 h and 1 kHz they are 1 GB): its
        figures, the noise and the viewer's recording read them a block or a chunk at a time
        (:attr:`calibrated_rows`); ``--calibrated`` and the exports ask for them."""
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
        signals were made already, it reads only the still blocks' calibrated rows, a run of
        blocks at a time (:class:`StillSignals`)."""
        if "calibrated" in self.__dict__ or len(self.session.t_acc) < 2:
            return still_noise(self.calibrated, self.block_times)
        return still_noise(StillSignals(self.calibration, self.session), self.block_times)

    @property
    def raw_acc_norm(self) -> np.ndarray:
        """(N,) ``|a_raw|`` in the calibrated unit through the whole-session fit's nominal frame:
        the uncalibrated magnitude beside ``calibrated.acc_norm``."""
        return self.raw_acc_norm_rows(0, len(self.session.t_acc))

    @property
    def raw_gyro_norm(self) -> np.ndarray | None:
        """(M,) ``|w_raw|`` in nominal rad/s (first segment's nominal, see
        :meth:`GyroFit.nominal_rate`) beside ``calibrated.gyro_norm``; None without a fit."""
        s = self.session
        return None if not s.has_gyro else self.raw_gyro_norm_rows(0, len(s.t_gyro))

    # --- the same, a chunk of rows at a time (the viewer reads a long session this way) ---

    def raw_acc_norm_rows(self, a: int, b: int) -> np.ndarray:
        """Rows ``[a, b)`` of :attr:`raw_acc_norm`, the same to the bit (row by row
        arithmetic): no signal-sized array."""
        return self.whole.nominal_norm(self.session.acc[a:b])

    def raw_gyro_norm_rows(self, a: int, b: int) -> np.ndarray | None:
        """Rows ``[a, b)`` of :attr:`raw_gyro_norm`, the same to the bit; None without a
        gyroscope fit."""
        s, fit = self.session, self.segments[0].gyro
        if not s.has_gyro or fit is None:
            return None
        return np.linalg.norm(fit.nominal_rate(s.gyro[a:b], s.gyro_unit), axis=1)

    @property
    def calibrated_rows(self) -> StillSignals:
        """The calibrated signals as row getters (``acc(a, b)``, ``gyro(a, b)`` or None):
        bit for bit the rows of :attr:`calibrated`, without making it."""
        return StillSignals(self.calibration, self.session)

    def row_edges(self, which: str, rows: int = CHUNK_ROWS) -> np.ndarray:
        """Edges ``0 = e_0 < e_1 < ... = N`` of chunks of at most ``rows`` rows of the
        accelerometer (``"acc"``) or the gyroscope (``"gyro"``), cut where the calibration's
        pieces (segments and the gaps between them) start and then every ``rows`` rows: on
        these edges ``calibrated_rows`` computes each row once (``Calibration.rows`` works on
        the grid of its pieces; elsewhere a chunk costs two of that grid's chunks)."""
        s = self.session
        t = s.t_acc if which == "acc" else s.t_gyro
        if t is None:
            return np.zeros(1, np.int64)
        n = len(t)
        # The pieces' edges depend on the clock and the segments' times only: the
        # accelerometer's models stand in for a gyroscope that has none.
        pieces = segment_pieces(t, self.calibration.segments, "acc")
        starts = [p0 for p0, p1, _ in pieces if p1 > p0]
        edges = [np.arange(p0, p1, rows) for p0, p1 in zip(starts, [*starts[1:], n])]
        return np.unique(np.concatenate([*edges, [0, n]])).astype(np.int64)


class StillSignals:
    """The calibrated signals as row getters, in place of :class:`CalibratedSignals` for the
    noise (:func:`imucal.stages.noise.still_noise`): the session's own time arrays, and
    ``acc(a, b)`` / ``gyro(a, b)`` the calibrated rows ``[a, b)`` (``Calibration.rows``, bit
    for bit the whole's). The noise asks only for the still blocks' rows, a run of blocks at a
    time, so neither the signals nor their still samples are ever made whole."""

    def __init__(self, calibration: Calibration, session: Session):
        self.calibration, self.session = calibration, session
        self.acc_unit = calibration.acc_unit
        self.t_acc = session.t_acc
        self.t_gyro = session.t_gyro

    def acc(self, a: int, b: int) -> np.ndarray:
        return self.calibration.rows(self.session, "acc", a, b)

    def _gyro(self, a: int, b: int) -> np.ndarray:
        return self.calibration.rows(self.session, "gyro", a, b)

    @property
    def gyro(self) -> Callable[[int, int], np.ndarray] | None:
        """The calibrated gyroscope's row getter; None without a calibrated gyroscope."""
        return self._gyro if self.calibration.applies_gyro(self.session) else None
