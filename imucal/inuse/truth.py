"""What a synthetic recording of everyday use is made from and with (method.md §10): how the
sensor drifted since it was calibrated (:class:`Drift`) and what made the recording
(:class:`EverydayTruth`), shared by :mod:`imucal.inuse.everyday` (carried by hand, on a desk)
and :mod:`imucal.inuse.flight` (a multirotor's log), which both make their body rate the same
way (:data:`H`). Kept apart from both so that everyday.py, which dispatches to flight.py, is the
one on top: imports run one way.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from imucal.models import SensorModel

H = 1e-4  # s: the half step of the body rate's difference (O(h^2): 1e-8 of the rate)


@dataclass(frozen=True)
class Drift:
    """How the sensor changed since it was calibrated, in its raw units: the gyroscope's bias
    moved by ``gyro_bias`` (rad/s), the accelerometer's by ``acc_bias`` (g), each accelerometer
    scale multiplied by ``1 + acc_scale``."""

    gyro_bias: np.ndarray = field(default_factory=lambda: np.zeros(3))
    acc_bias: np.ndarray = field(default_factory=lambda: np.zeros(3))
    acc_scale: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def apply(self, acc: SensorModel, gyro: SensorModel) -> tuple[SensorModel, SensorModel]:
        return (SensorModel(T=acc.T, K=acc.K * (1 + np.asarray(self.acc_scale, float)),
                            b=acc.b + np.asarray(self.acc_bias, float)),
                SensorModel(T=gyro.T, K=gyro.K, b=gyro.b + np.asarray(self.gyro_bias, float)))


@dataclass(frozen=True)
class EverydayTruth:
    """What made a recording of everyday use: the calibration as stored (before the drift) and
    the sensor as it is now, the rests (``still``: [t0, t1) where the device really lay still,
    taps and vibration cut out), the taps' times and the stretches of tapping and of typing."""

    activity: str
    stored_acc: SensorModel
    stored_gyro: SensorModel
    acc: SensorModel
    gyro: SensorModel
    drift: Drift
    still: np.ndarray  # (S, 2) s
    taps: np.ndarray  # (T,) s, the start of each pulse
    disturbed: np.ndarray  # (D, 2) s: tapping bursts and typing, where no moment may be found
    acc_noise: float  # g per axis per sample
    gyro_noise: float  # rad/s per axis per sample
    rate: float

    def to_dict(self) -> dict:
        def m(model: SensorModel) -> dict:
            return {"T": model.T.tolist(), "K": model.K.tolist(), "b": model.b.tolist()}

        return {"activity": self.activity, "stored": {"accelerometer": m(self.stored_acc),
                                                      "gyroscope": m(self.stored_gyro)},
                "accelerometer": m(self.acc), "gyroscope": m(self.gyro),
                "drift": {"gyro_bias_rad_s": self.drift.gyro_bias.tolist(),
                          "acc_bias_g": self.drift.acc_bias.tolist(),
                          "acc_scale": self.drift.acc_scale.tolist()},
                "still_intervals": self.still.tolist(), "taps": self.taps.tolist(),
                "disturbed_intervals": self.disturbed.tolist(),
                "noise": {"accelerometer_g": self.acc_noise, "gyroscope_rad_s": self.gyro_noise},
                "rate_hz": self.rate, "g": 1.0,
                "model": "a = T K (a_raw - b); w = T_g K_g (w_raw - b_g) (method.md M2, M4); "
                         "'stored' is the calibration before the drift"}
