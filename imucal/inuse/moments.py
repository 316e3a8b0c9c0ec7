"""Still moments of everyday use (method.md §10): the M1 detector of §1 with values for a few
seconds of rest, on the calibrated signals, and what each moment tells.

For each moment: its raw and calibrated accelerometer means and the scatter of its norm (for
M9), and the gyroscope's rate at rest left over by the calibration with the tilt the
accelerometer saw removed (M10), with its standard error."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from imucal.models import SensorModel
from imucal.numerics.directions import distinct_orientations
from imucal.numerics.windows import block_means
from imucal.stages.detect_runs import streamed_still_runs
from imucal.stages.detect_stat import CleanRows, Statistic
from imucal.stages.detect_tuning import quiet_level

# The detector's values for moments of use (method.md §10): a 0.5 s window (the variance of a
# sway of 0.2-0.6 Hz stays small over it), a shortest moment of 2 s, each axis' variance up to
# 3 times the sensor's own (k = 3^2 on M1, which squares the variances).
WINDOW_S = 0.5
MIN_MOMENT_S = 2.0
K_INUSE = 9.0
QUIET_QUANTILE = 0.01  # no stored noise: the quietest 1 % of the windows give the level
MAX_RATE_DEG_S = 3.0  # x-io Fusion's: a steady turn about gravity leaves the accelerometer still
MAX_NORM_OFF = 0.10  # a moment's mean norm within 10 % of |g|
MIN_MOMENT_SAMPLES = 10  # whatever the rate: a mean and a scatter need a few samples
EDGE_S = 0.5  # the ends of a moment whose gravity directions give its tilt (M10)
EMPTY = np.zeros(0, np.int64)
FLAT_SIGMA_G = 1e-5  # below any sensor's noise per sample (10 ug); far above rounding


class ModelRows:
    """A raw signal seen through a sensor model (M2, M4), row slices at a time: what the
    detector and the moments read, without a calibrated copy the length of a day's recording
    (at 100 Hz a day of one triad is 207 MB in float64)."""

    ndim = 2
    dtype = np.dtype(np.float64)

    def __init__(self, raw, model: SensorModel):
        self.raw, self.model = raw, model
        self.shape = (len(raw), int(raw.shape[1]))

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, key) -> np.ndarray:
        return self.model.apply(np.asarray(self.raw[key], dtype=np.float64))


@dataclass(frozen=True)
class Moments:
    """The still moments found, and how they were found.

    Arrays have one row per moment; the gyroscope's are None without a gyroscope."""

    blocks: np.ndarray  # (B, 2) int: [start, end) accelerometer samples
    times: np.ndarray  # (B, 2) s
    n: np.ndarray  # (B,) accelerometer samples
    raw_mean: np.ndarray  # (B, 3) raw accelerometer mean (M9's m_k)
    cal_mean: np.ndarray  # (B, 3) calibrated accelerometer mean
    norm_var: np.ndarray  # (B,) variance of the moment's mean norm (its scatter over n)
    rate: np.ndarray | None  # (B, 3) rad/s: M10's r_k, calibrated frame
    rate_se: np.ndarray | None  # (B, 3) rad/s, its standard error per axis
    window: int  # samples
    min_len: int  # samples
    k: float
    threshold: float
    level: float  # s2_ref
    level_from: str  # where s2_ref came from, in words
    rejected: dict[str, int]  # runs long enough but refused: reason -> count
    orientations: int

    @property
    def count(self) -> int:
        return len(self.blocks)

    @property
    def durations(self) -> np.ndarray:
        return self.times[:, 1] - self.times[:, 0]


def find_moments(acc_raw, acc_cal, t_acc: np.ndarray, gyro_cal, t_gyro: np.ndarray | None,
                 g: float, noise_sigma: float | None, rate: float) -> Moments:
    """The still moments of a recording (method.md §10), on its calibrated accelerometer
    ``acc_cal`` (and gyroscope ``gyro_cal``, rad/s): arrays, or :class:`ModelRows` read a
    slice at a time. ``noise_sigma`` is the accelerometer's white noise per sample and axis in
    the calibrated unit (None: not stored)."""
    window = max(3, int(round(WINDOW_S * rate)) | 1)
    min_len = max(window, MIN_MOMENT_SAMPLES, int(round(MIN_MOMENT_S * rate)))  # after trim
    if len(acc_cal) < min_len + window:  # too short to hold one moment (a 6-sample log)
        return _none(window, min_len, gyro_cal is not None and t_gyro is not None)
    # No outlier replacement (as §1 does): a tap lasts a sample or two and must end a moment.
    stat = Statistic(CleanRows(acc_cal, EMPTY), window)
    if noise_sigma is not None and noise_sigma > 0:
        level = 3.0 * noise_sigma**4  # M1 of white noise: 3 axes of variance sigma^2, squared
        level_from = (f"the stored noise ({noise_sigma * 1e3:.3g} m{_unit(g)} per sample and "
                      "axis)")
    else:
        s2 = np.concatenate([s for _, _, s in stat.spans()])
        # Flat windows (every axis constant: a coarse quantiser at rest; M1 is then rounding
        # error) say nothing of the noise, as in §1's quiet level; kept, they make the level
        # about 0 and nothing still.
        level = quiet_level(s2, QUIET_QUANTILE, flat=3.0 * (FLAT_SIGMA_G * g) ** 4)
        level_from = "the quietest 1 % of the recording's windows (no noise stored)"
    threshold = K_INUSE * level
    runs = streamed_still_runs(stat, threshold, None, EMPTY)
    # Half a window off each end: a centred window reaches that far into a weak disturbance
    # (typing's vibration) before it crosses the threshold.
    runs = runs + np.array([window // 2, -(window // 2)])
    runs = runs[(runs[:, 1] - runs[:, 0]) >= min_len].reshape(-1, 2)
    n = (runs[:, 1] - runs[:, 0]).astype(np.int64)
    cal_mean = block_means(acc_cal, runs).reshape(-1, 3)
    rejected: dict[str, int] = {}
    keep = np.abs(np.linalg.norm(cal_mean, axis=1) - g) <= MAX_NORM_OFF * g
    rejected["mean norm more than 10 % from |g|"] = int(np.sum(~keep))
    rates = rate_se = None
    if gyro_cal is not None and t_gyro is not None and len(runs):
        times = np.column_stack([t_acc[runs[:, 0]], t_acc[runs[:, 1] - 1]])
        g0, g1 = np.searchsorted(t_gyro, times[:, 0]), np.searchsorted(t_gyro, times[:, 1],
                                                                          side="right")
        mean_w = np.array([gyro_cal[a:b].mean(axis=0) if b > a else np.full(3, np.inf)
                           for a, b in zip(g0, g1)])  # one per moment, not per sample
        fast = np.linalg.norm(mean_w, axis=1) > np.radians(MAX_RATE_DEG_S)
        rejected[f"mean rate above {MAX_RATE_DEG_S:g} deg/s"] = int(np.sum(keep & fast))
        keep &= ~fast
    runs, n, cal_mean = runs[keep], n[keep], cal_mean[keep]
    times = np.column_stack([t_acc[runs[:, 0]], t_acc[runs[:, 1] - 1]]).reshape(-1, 2)
    raw_mean = block_means(acc_raw, runs).reshape(-1, 3)
    norm_var = np.array([np.var(np.linalg.norm(acc_cal[a:b], axis=1), ddof=1) / (b - a)
                         for a, b in runs]).reshape(-1)
    if gyro_cal is not None and t_gyro is not None:
        rates, rate_se = _rates(acc_cal, t_acc, gyro_cal, t_gyro, runs, rate)
    return Moments(blocks=runs, times=times, n=n, raw_mean=raw_mean, cal_mean=cal_mean,
                   norm_var=norm_var, rate=rates, rate_se=rate_se, window=window,
                   min_len=min_len, k=K_INUSE, threshold=threshold, level=level,
                   level_from=level_from, rejected={k: v for k, v in rejected.items() if v},
                   orientations=distinct_orientations(cal_mean) if len(runs) else 0)


def _none(window: int, min_len: int, gyro: bool) -> Moments:
    z3, z = np.zeros((0, 3)), np.zeros(0)
    return Moments(blocks=np.zeros((0, 2), np.int64), times=np.zeros((0, 2)),
                   n=np.zeros(0, np.int64), raw_mean=z3, cal_mean=z3, norm_var=z,
                   rate=z3 if gyro else None, rate_se=z3 if gyro else None, window=window,
                   min_len=min_len, k=K_INUSE, threshold=float("nan"), level=float("nan"),
                   level_from="none: the recording is shorter than one moment", rejected={},
                   orientations=0)


def _unit(g: float) -> str:
    return "g" if g == 1.0 else "m/s^2"


def _rates(acc: np.ndarray, t_acc: np.ndarray, gyro: np.ndarray, t_gyro: np.ndarray,
           runs: np.ndarray, rate: float) -> tuple[np.ndarray, np.ndarray]:
    """M10 for each moment: the mean calibrated rate between the centres of its two ends,
    less the tilt from the first end's gravity direction to the last's over that time; and
    the standard error per axis (the rate's scatter over its samples, the two directions'
    over theirs). A loop over moments (tens), each one's samples in numpy."""
    edge = max(2, int(round(EDGE_S * rate)))
    out = np.zeros((len(runs), 3))
    se = np.zeros((len(runs), 3))
    for i, (a, b) in enumerate(runs):
        e = min(edge, (b - a) // 3)
        first, last = acc[a:a + e], acc[b - e:b]
        m0, m1 = first.mean(axis=0), last.mean(axis=0)
        u0, u1 = m0 / np.linalg.norm(m0), m1 / np.linalg.norm(m1)
        c0, c1 = t_acc[a:a + e].mean(), t_acc[b - e:b].mean()
        g0, g1 = np.searchsorted(t_gyro, [c0, c1])
        w = gyro[g0:g1]
        span = c1 - c0
        phi = np.cross(u1, u0)  # the body's turn seen in gravity (M10)
        out[i] = w.mean(axis=0) - phi / span
        var_u = (first.var(axis=0, ddof=1) / np.dot(m0, m0)
                 + last.var(axis=0, ddof=1) / np.dot(m1, m1)) / e
        se[i] = np.sqrt(w.var(axis=0, ddof=1) / max(len(w), 1) + var_u / span**2)
    return out, se
