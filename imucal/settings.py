"""Every setting of method.md, declared once: its name, its default, its meaning.

``Settings`` is the one record a run is configured with. Each field's name is the command
line's flag (``window`` is ``--window``, ``gyro_sensitivity`` is ``--gyro-sensitivity``; ``lam``
is ``--lambda``, a Python keyword) and the key in calib.json's ``settings``; the defaults are
written here and nowhere else. Each stage reads the part it needs as a small typed record
(``Settings.detect`` ...), built from these fields and carrying no defaults of its own.

Kept free of numpy and scipy so that the command line can show the defaults without importing
them.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

# The thesis's initial still interval (method.md §1), s from the first sample: used when still.
THESIS_INIT: tuple[float, float] = (0.5, 3.0)

# L-curve grid (method.md §3): three points a decade from 1e-8 to 1e3.
DEFAULT_LAMBDAS: tuple[float, ...] = tuple(10.0 ** (i * (11 / 33) - 8) for i in range(34))


@dataclass(frozen=True)
class Settings:
    """Every setting of method.md, flat, with the thesis's defaults where it has one."""

    # --- static detector (§1) ---
    # None: chosen from the recording (imucal.stages.detect_tuning; method.md §1); a value
    # given always wins. Window and shortest still block in samples (thesis: 101 and 100 at
    # 100 Hz), the threshold multiplier on the reference level (thesis: 2) and the initial
    # still interval in s from the first sample (thesis: 0.5-3 s, used when it is still).
    window: int | None = None
    min_len: int | None = None
    k: float | None = None
    init: tuple[float, float] | None = None
    statistic: str = "thesis"  # "thesis": M1, sum of squared variances; "imu_tk": their norm
    # --- grouping (§2) ---
    single_segment: bool = False  # imu_tk's behaviour: one segment for the whole session
    # A stretch of blocks is split where one calibration explains its block means worse than
    # two by more than the noise does: an F-test at this level (Bonferroni over boundaries).
    split_alpha: float = 0.001
    # Or, given, the thesis's fixed threshold (its code: 0.01 g, its text: 0.02 g) on the
    # change of the calibrated still magnitude, relative to |g|; None: decided by the test.
    delta: float | None = None
    min_blocks: int = 12  # fewest still blocks a segment may have
    # --- accelerometer (§3) ---
    g: float | None = None  # |g| of the calibrated output; None: 1 g, or 9.80665 in m/s^2
    lam: float | str = "auto"  # Tikhonov lambda: "auto" (L-curve corner) or a value >= 0
    lambdas: tuple[float, ...] = DEFAULT_LAMBDAS  # the L-curve's grid
    # How still samples become fit points: "ml" (default) one residual per block, its mean,
    # weighted by sqrt(n) and with the noise bias of the norm removed (maximum likelihood);
    # "mean" the plain block means; "chunks" n_group chunk means per block; "thesis" §3.2.
    points: str = "ml"
    n_select: int = 99  # thesis points: samples spread over each block...
    n_group: int = 10  # ... averaged in groups of this many (also the chunks per block)
    # --- gyroscope (§4) ---
    gyro_lambda: float = 1e-4  # Tikhonov lambda of the gyroscope fit
    gyro_bias: str = "all"  # "all" still blocks of the segment, or the "first" (thesis)
    # Fit the bias too (its prior the still-block estimate): True or False, or None to keep
    # whichever predicts held-out turns better (cross-validation over the turns, §5).
    optimise_gyro_bias: bool | None = None
    gyro_sensitivity: float | None = None  # rad/s per raw count (datasheet), for "before"

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["init"] = None if self.init is None else list(self.init)
        d["lambdas"] = list(self.lambdas)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> Settings:
        """The inverse of :meth:`to_dict` (unknown keys are refused by the constructor)."""
        d = dict(d)
        if d.get("init") is not None:
            d["init"] = tuple(d["init"])
        if "lambdas" in d:
            d["lambdas"] = tuple(d["lambdas"])
        return cls(**d)

    @property
    def detect(self) -> DetectSettings:
        return DetectSettings(window=self.window, min_len=self.min_len, k=self.k,
                              init=None if self.init is None else tuple(self.init),
                              statistic=self.statistic)

    @property
    def group(self) -> GroupSettings:
        return GroupSettings(single_segment=self.single_segment, alpha=self.split_alpha,
                             delta=self.delta, min_blocks=self.min_blocks)

    @property
    def acc(self) -> AccSettings:
        return AccSettings(lam=self.lam, lambdas=tuple(self.lambdas), points=self.points,
                           n_select=self.n_select, n_group=self.n_group)

    @property
    def gyro(self) -> GyroSettings:
        return GyroSettings(lam=self.gyro_lambda, bias=self.gyro_bias,
                            optimise_bias=self.optimise_gyro_bias,
                            nominal_scale=self.gyro_sensitivity)


# What each stage reads (see the fields of Settings for their meaning and defaults).


@dataclass(frozen=True)
class DetectSettings:
    window: int | None
    min_len: int | None
    k: float | None
    init: tuple[float, float] | None
    statistic: str


@dataclass(frozen=True)
class GroupSettings:
    single_segment: bool
    alpha: float  # Settings.split_alpha
    delta: float | None
    min_blocks: int


@dataclass(frozen=True)
class AccSettings:
    lam: float | str
    lambdas: tuple[float, ...]
    points: str
    n_select: int
    n_group: int


@dataclass(frozen=True)
class GyroSettings:
    lam: float
    bias: str
    optimise_bias: bool | None  # None: chosen by cross-validation
    nominal_scale: float | None  # rad/s per raw unit (Settings.gyro_sensitivity)
