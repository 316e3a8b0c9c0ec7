"""The rows the Overview and Signals tabs log, and their plots' y ranges, made with the signals
read a chunk of rows at a time (issue 12: a worker's memory is bounded by the session).

A 6-hour 1 kHz session's calibrated signals are 1 GB whole, its magnitudes 350 MB, and the
recording logs ~20 000 rows of each (:mod:`viewer.decimate`). So nothing signal-sized is made
here: each sensor is read once, ``CHUNK`` rows at a time (the raw rows, the calibrated ones
``Result.calibrated_rows`` makes, the magnitudes), into the envelopes of its magnitude and its
axes (:class:`~viewer.stream.EnvelopeStream`) and the y range of its magnitude plot (exact
quantiles from the few smallest and largest magnitudes, :class:`~viewer.ranges.RobustRange`).
Every row and range is the one the whole arrays give, to the bit
(tests/viewer/test_signal_rows.py).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .columns import log10_axis
from .decimate import Decimation, axes_cut, magnitude_cut
from .ranges import RobustRange
from .stream import EnvelopeStream

if TYPE_CHECKING:
    from imucal.result import Result

CHUNK = 1 << 16  # rows read at once: 1.5 MB of (k, 3) float64
# How much of each end the magnitude plots leave out of their y range: the accelerometer's
# spikes (knocks) are short; the gyroscope's magnitude is mostly still, its turns the
# extremes a person looks at.
ACC_Q = 0.005
GYRO_Q = 0.0005

Rows = Callable[[int, int], np.ndarray]


@dataclass(frozen=True)
class Series:
    """One entity's rows: times, values ((R,) or (R, k)) and what the decimation chose."""

    t: np.ndarray
    v: np.ndarray
    decimation: Decimation


@dataclass(frozen=True)
class SensorRows:
    """A sensor's magnitude [raw, calibrated], its raw and calibrated axes, and the robust y
    range of its magnitude plot (None: the viewer's own)."""

    magnitude: Series
    raw: Series
    calibrated: Series
    y_range: tuple[float, float] | None


@dataclass(frozen=True)
class SignalRows:
    acc: SensorRows
    gyro: SensorRows | None  # None without a calibrated gyroscope
    detector: Series  # log10 of the statistic (M1)
    detector_range: tuple[float, float] | None  # with the threshold's log10 in it


def detector_statistic(result: Result) -> Iterator[np.ndarray]:
    """The detector's statistic s2 per accelerometer sample (M1), a span at a time in order:
    the one place the viewer reads it. It is not kept in the result: computed again from the
    accelerometer, the same values the detector saw, never whole."""
    return result.detection.statistic_chunks(result.session.acc)


def signal_rows(result: Result) -> SignalRows:
    """Everything :mod:`viewer.signals` logs of the signals, and the ranges the layout sets."""
    acc = _sensor(result, "acc")
    gyro = None
    if result.calibration.applies_gyro(result.session):  # a model in every segment
        gyro = _sensor(result, "gyro")
    det, det_range = _detector(result)
    return SignalRows(acc=acc, gyro=gyro, detector=det, detector_range=det_range)


def _spans(edges: np.ndarray) -> Iterator[tuple[int, int]]:
    yield from zip(edges[:-1].tolist(), edges[1:].tolist())


def _sensor(result: Result, which: str) -> SensorRows:
    s, cal = result.session, result.calibrated_rows
    if which == "acc":
        t, raw, still = s.t_acc, s.acc, result.detection.blocks
        cal_rows: Rows = cal.acc
        raw_norm: Rows = result.raw_acc_norm_rows
    else:
        t, raw, still = s.t_gyro, s.gyro, result.gyro_blocks
        cal_rows, raw_norm = cal.gyro, result.raw_gyro_norm_rows
    n = len(t)
    # The accelerometer's still samples at full rate (up to STILL_ROWS); the gyroscope's
    # count only through their mean, the bias of M4 (viewer.decimate says why).
    mag = EnvelopeStream(t, magnitude_cut(still, n, keep_still=which == "acc"))
    axes_raw, axes_cal = EnvelopeStream(t, axes_cut(n)), EnvelopeStream(t, axes_cut(n))
    y_range = RobustRange(2 * n, ACC_Q if which == "acc" else GYRO_Q)
    edges = result.row_edges(which, CHUNK)
    for a, b in _spans(edges):
        c = cal_rows(a, b)
        r, m = raw_norm(a, b), np.linalg.norm(c, axis=1)
        mag.feed(np.column_stack([r, m]))
        axes_raw.feed(raw[a:b])
        axes_cal.feed(c)
        y_range.add(r)
        y_range.add(m)

    def magnitudes() -> Iterator[np.ndarray]:  # again, only if the range needs them
        for a, b in _spans(edges):
            yield _finite(raw_norm(a, b))
            yield _finite(np.linalg.norm(cal_rows(a, b), axis=1))

    return SensorRows(Series(*mag.rows()), Series(*axes_raw.rows()), Series(*axes_cal.rows()),
                      y_range.result(magnitudes))


def _detector(result: Result) -> tuple[Series, tuple[float, float] | None]:
    """The statistic's log10 (NaN where it is not positive: not drawn) as an envelope, and
    the y range of it and the threshold: from the smallest to the largest value (q = 0)."""
    n = len(result.session.t_acc)
    rows = EnvelopeStream(result.session.t_acc, axes_cut(n))
    y_range = RobustRange(n + 1, q=0.0)
    for stat in detector_statistic(result):
        v = log10_axis(stat)
        rows.feed(v)
        y_range.add(v)
    threshold = log10_axis(np.array([result.detection.threshold]))
    y_range.add(threshold)

    def values() -> Iterator[np.ndarray]:  # a second pass, only if the kept tails missed
        for stat in detector_statistic(result):
            yield _finite(log10_axis(stat))
        yield _finite(threshold)

    return Series(*rows.rows()), y_range.result(values)


def _finite(v: np.ndarray) -> np.ndarray:
    ok = np.isfinite(v)
    return v if ok.all() else v[ok]
