"""Every setting of method.md in one flat, typed record, with the thesis's defaults.

Kept free of numpy and scipy so that the command line can show the defaults without importing
them; each stage's own settings record is built on demand.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .accel import AccSettings
    from .detect import DetectSettings
    from .group import GroupSettings
    from .gyro import GyroSettings


@dataclass(frozen=True)
class Settings:
    """Every setting of method.md, flat, with the thesis's defaults (see each module)."""

    # detector (§1)
    window: int | None = None
    min_len: int | None = None
    k: float = 2.0
    init: tuple[float, float] = (0.5, 3.0)
    statistic: str = "thesis"
    # grouping (§2)
    single_segment: bool = False
    delta: float = 0.01
    min_blocks: int = 12
    # accelerometer (§3)
    g: float | None = None
    lam: float | str = "auto"
    points: str = "chunks"
    # gyroscope (§4)
    gyro_lam: float = 1e-4
    gyro_bias: str = "all"
    optimise_gyro_bias: bool = False
    gyro_nominal_scale: float | None = None

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["init"] = list(self.init)
        return d

    @property
    def detect(self) -> DetectSettings:
        from .detect import DetectSettings

        return DetectSettings(window=self.window, min_len=self.min_len, k=self.k,
                              init=tuple(self.init), statistic=self.statistic)

    @property
    def group(self) -> GroupSettings:
        from .group import GroupSettings

        return GroupSettings(single_segment=self.single_segment, delta=self.delta,
                             min_blocks=self.min_blocks)

    @property
    def acc(self) -> AccSettings:
        from .accel import AccSettings

        return AccSettings(lam=self.lam, points=self.points)

    @property
    def gyro(self) -> GyroSettings:
        from .gyro import GyroSettings

        return GyroSettings(lam=self.gyro_lam, bias=self.gyro_bias,
                            optimise_bias=self.optimise_gyro_bias,
                            nominal_scale=self.gyro_nominal_scale)
