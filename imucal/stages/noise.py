"""The sensor's noise figures: white noise density, bias instability and random walk per axis.

Two sources, one estimator (:mod:`imucal.numerics.allan`, the overlapping Allan deviation and
the fit ``avar = N^2/tau + c + K^2 tau/3``):

- the still blocks of a calibration (method.md §1): the Allan variance pooled over the blocks,
  every cluster inside one block, so the pose changes between blocks do not count as noise.
  Blocks of a few seconds determine the white noise; bias instability and random walk need
  minutes to hours, so they are reported only where the curve shows them;
- a long still recording, streamed a chunk at a time (:class:`StreamingNoise`).

Units: the white noise density ``N`` is in ``unit/sqrt(Hz)`` (velocity random walk for the
accelerometer, angle random walk for the gyroscope), the random walk ``K`` in
``unit/s/sqrt(Hz)``, the bias instability in ``unit``, with ``unit`` the signal's (g, m/s^2 or
rad/s once calibrated; counts if raw counts are measured).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from imucal.numerics.allan import AllanAccumulator, AllanCurve, NoiseFit, Rows, fit_noise
from imucal.numerics.allan import pooled_allan_variance as _pooled
from imucal.numerics.rows import search_sorted
from imucal.session import chunked_median
from imucal.stages.apply import CalibratedSignals

AXES = ("x", "y", "z")
STEP_ROWS = 1 << 16  # times read at once for the steps inside the blocks
# Of |g|: above it the recording is not still (see StreamingNoise), and no Kalibr noise block
# is given from it. A tilt of 3 degrees moves a gravity component by 5 % of |g|, a turn by tens
# of percent (180 % at tau = 41 s on sample_data); the bias random walk of a poor MEMS part,
# 1e-3 (m/s^3)/sqrt(Hz), reaches 0.4 % in an hour, and the tests' strong synthetic one (5e-3)
# 1.2 % at tau = 655 s: noise, which a 1 % limit called motion.
MAX_STILL_DRIFT = 0.05
# unit of the signal -> (white noise density, random walk) units
DENSITY_UNITS = {
    "g": ("g/sqrt(Hz)", "g/s/sqrt(Hz)"),
    "m/s^2": ("m/s^2/sqrt(Hz)", "m/s^3/sqrt(Hz)"),
    "rad/s": ("rad/s/sqrt(Hz)", "rad/s^2/sqrt(Hz)"),
    "counts": ("counts/sqrt(Hz)", "counts/s/sqrt(Hz)"),
}
# What is not still in a still recording (a knock, a bump, someone picking it up) is found and
# left out before the Allan variance: one 3 g knock of five samples in 20 minutes raised the
# white noise density 12.6 times (issue 27). A sample is not still when it lies more than
# STILL_SIGMAS noise sigmas from the median of its STILL_BLOCK_S; the sigma is the robust one of
# the sample-to-sample steps (1.4826 MAD / sqrt 2), which a knock or a slow motion hardly moves.
# Eight sigmas: a Gaussian sample goes beyond once in 10^15. STILL_MARGIN_S either side goes
# with it (a knock rings).
STILL_SIGMAS = 8.0
STILL_BLOCK_S = 1.0
STILL_MARGIN_S = 0.5
MAX_MOTION = 0.5  # of the samples: a recording more not still than still is refused


@dataclass(frozen=True)
class SensorNoise:
    """One sensor's Allan curve and the figures fitted to each axis."""

    sensor: str  # "accelerometer" or "gyroscope"
    unit: str  # of the signal
    rate_hz: float
    curve: AllanCurve
    fits: tuple[NoiseFit, NoiseFit, NoiseFit]

    @property
    def taus(self) -> np.ndarray:
        return self.curve.lags / self.rate_hz

    def per_axis(self, name: str) -> list[float | None]:
        return [getattr(f, name) for f in self.fits]

    @property
    def white_unit(self) -> str:
        return DENSITY_UNITS.get(self.unit, (f"{self.unit}/sqrt(Hz)",))[0]

    @property
    def random_walk_unit(self) -> str:
        return DENSITY_UNITS.get(self.unit, ("", f"{self.unit}/s/sqrt(Hz)"))[1]

    def notes(self) -> list[str]:
        """Why figures are missing, once per reason (the axes usually agree)."""
        out: list[str] = []
        for f in self.fits:
            for w in f.why:
                key = w.split(":")[0]
                if not any(o.startswith(key) for o in out):
                    out.append(w)
        return out


@dataclass(frozen=True)
class NoiseReport:
    accelerometer: SensorNoise | None
    gyroscope: SensorNoise | None
    source: str  # where the samples came from, in words
    notes: tuple[str, ...] = field(default_factory=tuple)
    # A long recording that should be still: False where it moved (the figures then measure the
    # motion, and no noise block is given from them); None where not judged (still blocks).
    still: bool | None = None


def sensor_noise(sensor: str, unit: str, rate_hz: float, curve: AllanCurve) -> SensorNoise:
    rate_hz = float(f"{rate_hz:.10g}")  # a rate from timestamps: its last digits are rounding
    fits = tuple(fit_noise(curve, 1.0 / rate_hz, c) for c in range(3))
    return SensorNoise(sensor=sensor, unit=unit, rate_hz=rate_hz, curve=curve,
                       fits=fits)  # type: ignore[arg-type]


class RowSource(Protocol):
    """The calibrated signals as the noise reads them: each signal an (N, 3) array or a row
    getter ``rows(a, b)`` (then only the still blocks' rows are ever made, a run at a time)."""

    t_acc: np.ndarray
    acc: np.ndarray | Rows
    t_gyro: np.ndarray | None
    gyro: np.ndarray | Rows | None
    acc_unit: str


def still_noise(signals: CalibratedSignals | RowSource,
                 block_times: np.ndarray) -> NoiseReport | None:
    """Noise figures of the calibrated signals inside the still blocks ``[t_start, t_end)``.

    The time arrays are read through slices and gathers (the blocks' edges are searched a
    block of times at a time); a gyroscope on the accelerometer's own clock shares its search
    and its rate."""
    block_times = np.asarray(block_times, dtype=float).reshape(-1, 2)
    if len(block_times) == 0 or len(signals.t_acc) < 2:
        return None
    lengths = block_times[:, 1] - block_times[:, 0]
    source = (f"still blocks of the calibration: {len(block_times)} blocks, "
              f"{lengths.sum():.1f} s in all, longest {lengths.max():.2f} s; overlapping Allan "
              f"variance within each block, pooled over the blocks")
    clock = _BlockClock(signals.t_acc, block_times)
    x_acc, x_gyro = signals.acc, signals.gyro
    if signals.t_gyro is None or len(signals.t_gyro) < 2:
        x_gyro = None
    if x_gyro is not None and signals.t_gyro is signals.t_acc and callable(x_acc) and callable(
            x_gyro):
        # One clock, two row getters: both sensors' blocks in one pass, six columns side by
        # side. Each column's running sum, mean and sum of squares are the same operations in
        # the same order as with three (numpy reduces each column in order over the rows),
        # so each sensor's curve is its own to the bit; the still rows are read once, and
        # einsum's per-row cost is shared (it costs the same for six columns as for three).
        both = _pooled(_side_by_side(x_acc, x_gyro), clock.lo, clock.hi, width=6)
        curves = [AllanCurve(lags=both.lags, avar=np.ascontiguousarray(both.avar[:, c]),
                             terms=both.terms, stride=both.stride, n=both.n)
                  for c in (slice(0, 3), slice(3, 6))]
        return NoiseReport(accelerometer=_sensor("accelerometer", signals.acc_unit, clock,
                                                 curves[0]),
                           gyroscope=_sensor("gyroscope", "rad/s", clock, curves[1]),
                           source=source)
    acc = _sensor("accelerometer", signals.acc_unit, clock, _pooled(x_acc, clock.lo, clock.hi))
    gyro = None
    if x_gyro is not None:
        if signals.t_gyro is not signals.t_acc:
            clock = _BlockClock(signals.t_gyro, block_times)
        gyro = _sensor("gyroscope", "rad/s", clock, _pooled(x_gyro, clock.lo, clock.hi))
    return NoiseReport(accelerometer=acc, gyroscope=gyro, source=source)


def _side_by_side(acc: Rows, gyro: Rows) -> Rows:
    """The rows ``[a, b)`` of both getters as one (b - a, 6) C-ordered array."""
    def rows(a: int, b: int) -> np.ndarray:
        return np.hstack([np.asarray(acc(a, b), dtype=np.float64).reshape(b - a, 3),
                          np.asarray(gyro(a, b), dtype=np.float64).reshape(b - a, 3)])
    return rows


class _BlockClock:
    """The still blocks' ``[lo, hi)`` sample ranges on one clock and the rate inside them (the
    median step there: a recording's gaps lie elsewhere), found once per clock."""

    def __init__(self, t, block_times: np.ndarray):
        self.t = t
        self.lo = search_sorted(t, block_times[:, 0], side="left")
        self.hi = search_sorted(t, block_times[:, 1], side="left")
        self._rate: float | None = None

    @property
    def rate(self) -> float:
        if self._rate is None:  # np.median of the blocks' steps to the bit, not all at once
            self._rate = float(1.0 / chunked_median(self._steps, int(np.sum(
                np.maximum(self.hi - self.lo - 1, 0)))))
        return self._rate

    def _steps(self):
        """The blocks' steps (``np.diff`` within each), about ``STEP_ROWS`` at a time: the
        times of a run of blocks read at once, their steps put end to end."""
        lo, hi = self.lo, self.hi
        i = 0
        while i < len(lo):
            j = i + max(1, int(np.searchsorted(hi[i:], lo[i] + STEP_ROWS, side="right")))
            a, b = int(lo[i]), int(hi[j - 1])
            t = np.asarray(self.t[a:b], dtype=np.float64)
            yield np.concatenate([np.diff(t[p - a:q - a]) for p, q in zip(lo[i:j], hi[i:j])
                                  if q - p > 1] or [np.zeros(0)])
            i = j


def _sensor(sensor: str, unit: str, clock: _BlockClock, curve: AllanCurve
            ) -> SensorNoise | None:
    if len(curve.lags) == 0:
        return None
    return sensor_noise(sensor, unit, clock.rate, curve)


def not_still(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """The samples of ``x`` (n, 3) at times ``t`` that are not still: beyond ``STILL_SIGMAS``
    robust noise sigmas from the median of their block of about ``STILL_BLOCK_S``."""
    x = np.asarray(x, dtype=np.float64).reshape(len(t), -1)
    n = len(x)
    if n < 8:
        return np.zeros(n, dtype=bool)
    steps = np.diff(x, axis=0)
    sigma = 1.4826 * np.median(np.abs(steps - np.median(steps, axis=0)), axis=0) / np.sqrt(2)
    # Raw counts of a quiet sensor: most steps are 0 and the MAD with them; the plain
    # deviation of the steps then (a knock inflates it, but by far less than its own size).
    sigma = np.where(sigma > 0, sigma, np.std(steps, axis=0) / np.sqrt(2))
    dt = float(np.median(np.diff(t[: min(n, 4096)])))
    width = int(np.clip(STILL_BLOCK_S / dt if dt > 0 else 16, 16, n))
    full = n // width * width
    level = np.empty_like(x)
    level[:full] = np.repeat(np.median(x[:full].reshape(-1, width, x.shape[1]), axis=1),
                             width, axis=0)
    if full < n:
        level[full:] = np.median(x[max(0, n - width):], axis=0)
    off = np.abs(x - level) > STILL_SIGMAS * sigma
    off[:, sigma == 0] = False  # a constant axis: nothing moves it
    return off.any(axis=1)


def _stretches(t: np.ndarray, off: np.ndarray, margin: float) -> np.ndarray:
    """The (k, 2) time intervals of the runs of ``off``, widened by ``margin`` either side."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], off.view(np.int8), [0]])))
    starts, ends = edges[0::2], edges[1::2] - 1
    return np.column_stack([t[starts] - margin, t[ends] + margin])


def _merge(spans: np.ndarray) -> np.ndarray:
    """Overlapping intervals joined, sorted by start."""
    if len(spans) == 0:
        return spans.reshape(0, 2)
    spans = spans[np.argsort(spans[:, 0], kind="stable")]
    reach = np.maximum.accumulate(spans[:, 1])
    new = np.concatenate([[True], spans[1:, 0] > reach[:-1]])
    first = np.flatnonzero(new)
    last = np.concatenate([first[1:], [len(spans)]]) - 1
    return np.column_stack([spans[first, 0], reach[last]])


def _inside(t: np.ndarray, spans: np.ndarray) -> np.ndarray:
    if len(spans) == 0:
        return np.zeros(len(t), dtype=bool)
    i = np.searchsorted(spans[:, 0], t, side="right") - 1
    return (i >= 0) & (t <= spans[np.maximum(i, 0), 1])


class StreamingNoise:
    """Noise figures of a long still recording fed a chunk at a time, in bounded memory: two
    :class:`AllanAccumulator` (a few KB each) plus the clock's first and last times.

    :meth:`feed` leaves out what is not still (:func:`not_still`, on either sensor: a knock
    moves both), each left-out stretch a gap no Allan cluster spans."""

    def __init__(self, acc_unit: str, gyro_unit: str | None) -> None:
        self.units = {"accelerometer": acc_unit, "gyroscope": gyro_unit}
        self.acc = {"accelerometer": AllanAccumulator(3), "gyroscope": AllanAccumulator(3)}
        self.clock: dict[str, list[float]] = {}  # sensor -> [t_first, t_last, n, step, gaps]
        self.left_out = {"accelerometer": 0, "gyroscope": 0}  # samples not still
        self.stretches: list[float] = [0, 0.0, float("nan")]  # count, seconds, first start
        self._until = -np.inf  # a stretch reaching into the next chunk ends here
        self._gap = {"accelerometer": False, "gyroscope": False}  # last sample left out

    def feed(self, signals: dict[str, tuple[np.ndarray, np.ndarray]]) -> None:
        """One chunk: sensor -> (times, (n, 3) samples), the times continuous with the last
        chunk's. The samples that are not still, with a margin, are left out."""
        spans = [_stretches(t, not_still(t, x), STILL_MARGIN_S)
                 for t, x in signals.values() if len(t)]
        spans.append(np.array([[-np.inf, self._until]]))
        spans = _merge(np.concatenate(spans))
        ends = [float(t[-1]) for t, _ in signals.values() if len(t)]
        if ends:
            self._until = max(self._until, float(spans[:, 1].max()))
            new = spans[spans[:, 0] > -np.inf]
            if len(new):
                self.stretches[0] += len(new)
                self.stretches[1] += float(np.sum(np.minimum(new[:, 1], max(ends))
                                                  - new[:, 0]))
                if not np.isfinite(self.stretches[2]):
                    self.stretches[2] = float(new[0, 0] + STILL_MARGIN_S)
        for sensor, (t, x) in signals.items():
            off = _inside(t, spans)
            self.left_out[sensor] += int(np.count_nonzero(off))
            self.update(sensor, t, x, keep=~off)

    def update(self, sensor: str, t: np.ndarray, x: np.ndarray,
               keep: np.ndarray | None = None) -> None:
        """Samples of one sensor; ``keep`` False for those left out (a gap in the Allan
        clusters, while the clock counts every sample)."""
        if len(t) == 0:
            return
        c = self.clock.get(sensor)
        if c is None:
            step = float(np.median(np.diff(t))) if len(t) > 1 else float("nan")
            c = self.clock[sensor] = [float(t[0]), float(t[0]), 0.0, step, 0.0]
        steps = np.diff(np.concatenate([[c[1]], t])) if c[2] else np.diff(t)
        if np.isfinite(c[3]):
            c[4] += float(np.count_nonzero(steps > 1.5 * c[3]))
        c[1] = float(t[-1])
        c[2] += len(t)
        if keep is None or keep.all():
            if self._gap[sensor] and self.acc[sensor].n:
                self.acc[sensor].restart()
            self.acc[sensor].update(x)
            self._gap[sensor] = False
            return
        edges = np.flatnonzero(np.diff(np.concatenate([[0], keep.view(np.int8), [0]])))
        for a, b in zip(edges[0::2], edges[1::2]):  # the still runs (a few per knock)
            if (a > 0 or self._gap[sensor]) and self.acc[sensor].n:
                self.acc[sensor].restart()
            self.acc[sensor].update(x[a:b])
        self._gap[sensor] = not keep[-1]

    def moving_fraction(self) -> float:
        """The largest share of a sensor's samples left out as not still."""
        return max((self.left_out[s] / c[2] for s, c in self.clock.items() if c[2]),
                   default=0.0)

    def report(self, source: str) -> NoiseReport:
        out: dict[str, SensorNoise | None] = {"accelerometer": None, "gyroscope": None}
        notes = []
        still = True
        for sensor, c in self.clock.items():
            t0, t1, n, _step, gaps = c
            if n < 2 or t1 <= t0:
                continue
            rate = (n - 1) / (t1 - t0)  # mean rate over the whole record
            if gaps:
                notes.append(f"{sensor}: {int(gaps)} gaps longer than 1.5 sample periods; the "
                             f"estimator assumes even sampling at {rate:.6g} Hz")
            curve = self.acc[sensor].curve()
            centre = self.acc[sensor].centre
            if sensor == "accelerometer" and len(curve.lags) and centre is not None:
                # A still accelerometer's mean drifts by far less than 1 % of |g| (bias
                # instability of MEMS parts: 0.01-1 mg); a turn moves it by tens of percent.
                # The largest tau's deviation against MAX_STILL_DRIFT (see there).
                moved = float(np.sqrt(curve.avar[-1].max()) / max(np.linalg.norm(centre), 1e-300))
                if moved > MAX_STILL_DRIFT:
                    still = False
                    notes.append(f"the recording does not look still: the accelerometer's "
                                 f"Allan deviation at tau = {curve.lags[-1] / rate:.3g} s is "
                                 f"{100 * moved:.2g} % of its mean magnitude; the figures "
                                 "measure the motion")
            if len(curve.lags):
                out[sensor] = sensor_noise(sensor, self.units[sensor] or "", rate, curve)
        if self.stretches[0]:
            count, seconds, first = self.stretches
            notes.append(f"left out {int(count)} stretch{'es' if count != 1 else ''} that "
                         f"{'are' if count != 1 else 'is'} not still (a knock or motion: "
                         f"{100 * self.moving_fraction():.2g} % of the samples, {seconds:.3g} s "
                         f"with {STILL_MARGIN_S:g} s either side; the first at t = {first:.6g} "
                         "s); the figures are from the still rest, no Allan cluster spans a "
                         "gap")
        return NoiseReport(accelerometer=out["accelerometer"], gyroscope=out["gyroscope"],
                           source=source, notes=tuple(notes), still=still)
