"""A calibration that knows its units, its model and its format, and cannot be misapplied.

``Calibration.apply`` turns a raw session into calibrated signals: each segment's models over
its own time span, the parameter-wise mean of the two neighbours' between two segments
(method.md §2). The first segment extends back to the start of time and the last to its end,
so a one-segment calibration applies to any later recording of the same device.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from imucal.errors import ImucalError
from imucal.models import SensorModel
from imucal.session import Session


@dataclass(frozen=True)
class SegmentModels:
    t_start: float
    t_end: float
    acc: SensorModel
    gyro: SensorModel | None


@dataclass(frozen=True)
class Calibration:
    segments: tuple[SegmentModels, ...]
    acc_unit_raw: str  # "g", "m/s^2" or "counts"
    acc_unit: str  # unit of the calibrated accelerometer ("g" or "m/s^2")
    g: float  # |g| in acc_unit
    gyro_unit_raw: str | None  # "rad/s" or "counts" (deg/s input is converted on load)

    def check_units(self, session: Session) -> None:
        """Refuse a session in other units than the calibration was fitted on (style.md)."""
        if session.acc_unit != self.acc_unit_raw:
            raise ImucalError(f"the calibration was fitted on an accelerometer in "
                              f"{self.acc_unit_raw}, this session is in {session.acc_unit}",
                              source=session.source, field="accelerometer unit")
        if session.has_gyro and self.gyro_unit_raw and session.gyro_unit != self.gyro_unit_raw:
            raise ImucalError(f"the calibration was fitted on a gyroscope in "
                              f"{self.gyro_unit_raw}, this session is in {session.gyro_unit}",
                              source=session.source, field="gyroscope unit")

    def apply(self, session: Session) -> CalibratedSignals:
        self.check_units(session)
        acc = _apply_piecewise(session.acc, session.t_acc, self.segments, "acc")
        gyro = None
        if session.has_gyro and all(s.gyro is not None for s in self.segments):
            gyro = _apply_piecewise(session.gyro, session.t_gyro, self.segments, "gyro")
        return CalibratedSignals(t_acc=session.t_acc, acc=acc, t_gyro=session.t_gyro,
                                 gyro=gyro, acc_unit=self.acc_unit)


@dataclass(frozen=True)
class CalibratedSignals:
    t_acc: np.ndarray
    acc: np.ndarray
    t_gyro: np.ndarray | None
    gyro: np.ndarray | None  # rad/s
    acc_unit: str

    @property
    def acc_norm(self) -> np.ndarray:
        return np.linalg.norm(self.acc, axis=1)

    @property
    def gyro_norm(self) -> np.ndarray | None:
        return None if self.gyro is None else np.linalg.norm(self.gyro, axis=1)


def _apply_piecewise(raw: np.ndarray, t: np.ndarray, segments: tuple[SegmentModels, ...],
                     which: str) -> np.ndarray:
    """Each sample through its segment's model, or the mean of the neighbours' in a gap.

    Vectorised: the samples of one piece are a contiguous slice found by searchsorted, so the
    work is one matrix product per piece, not per sample.
    """
    out = np.empty(raw.shape, dtype=np.float64)
    n_seg = len(segments)
    models = [getattr(s, which) for s in segments]
    # Piece boundaries: segment i owns [start_i, end_i]; gap i (between i and i+1) the rest.
    starts = [-np.inf] + [s.t_start for s in segments[1:]]
    ends = [s.t_end for s in segments[:-1]] + [np.inf]
    for i in range(n_seg):
        lo = np.searchsorted(t, starts[i], side="left")
        hi = np.searchsorted(t, ends[i], side="right")
        _apply_into(models[i], raw[lo:hi], out[lo:hi])
        if i + 1 < n_seg:
            g_hi = np.searchsorted(t, starts[i + 1], side="left")
            if g_hi > hi:
                _apply_into(SensorModel.mean(models[i], models[i + 1]), raw[hi:g_hi],
                            out[hi:g_hi])
    return out


CHUNK_ROWS = 1 << 16


def _apply_into(model: SensorModel, raw: np.ndarray, out: np.ndarray) -> None:
    """``out = model.apply(raw)`` (M2/M4, ``T K (raw - b)``), a cache-sized chunk at a time.

    The same arithmetic as :meth:`SensorModel.apply`, without its two signal-sized temporaries:
    at 1 kHz for 90 minutes each is 130 MB of fresh pages, and the page faults cost more than
    the arithmetic and made this stage's time per sample vary 3x between runs (bench/).
    """
    M = model.matrix.T
    tmp = np.empty((min(CHUNK_ROWS, len(raw)), raw.shape[1]))
    for lo in range(0, len(raw), CHUNK_ROWS):
        hi = min(lo + CHUNK_ROWS, len(raw))
        d = tmp[:hi - lo]
        np.subtract(raw[lo:hi], model.b, out=d)
        np.matmul(d, M, out=out[lo:hi])
