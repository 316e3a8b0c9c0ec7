"""The sensor models of method.md: small value types used by the fit, the output and apply.

Accelerometer (M2): ``a = T K (a_raw - b)`` with ``T`` upper unitriangular (3 angles).
Gyroscope (M4): ``w = T_g K_g (w_raw - b_g)`` with ``T_g`` unit-diagonal (6 angles).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

ACC_PARAM_NAMES = ("a_yz", "a_zy", "a_zx", "s_x", "s_y", "s_z", "b_x", "b_y", "b_z")
GYRO_PARAM_NAMES = ("g_yz", "g_zy", "g_xz", "g_zx", "g_xy", "g_yx", "s_x", "s_y", "s_z")
ACC_THETA0 = np.array([0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0])
GYRO_THETA0 = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0])


def acc_T(theta: np.ndarray) -> np.ndarray:
    """Misalignment of M2: [[1, -a_yz, a_zy], [0, 1, -a_zx], [0, 0, 1]]."""
    a_yz, a_zy, a_zx = theta[0], theta[1], theta[2]
    return np.array([[1.0, -a_yz, a_zy], [0.0, 1.0, -a_zx], [0.0, 0.0, 1.0]])


def gyro_T(theta: np.ndarray) -> np.ndarray:
    """Misalignment of M4: [[1, g_yz, g_zy], [g_xz, 1, g_zx], [g_xy, g_yx, 1]]."""
    g_yz, g_zy, g_xz, g_zx, g_xy, g_yx = theta[:6]
    return np.array([[1.0, g_yz, g_zy], [g_xz, 1.0, g_zx], [g_xy, g_yx, 1.0]])


@dataclass(frozen=True)
class SensorModel:
    """``x = T K (x_raw - b)``: the common shape of M2 and M4, in the raw signal's units."""

    T: np.ndarray  # (3, 3)
    K: np.ndarray  # (3,)
    b: np.ndarray  # (3,)

    @property
    def matrix(self) -> np.ndarray:
        return self.T * self.K[None, :]

    def apply(self, raw: np.ndarray) -> np.ndarray:
        """Calibrate (N, 3) raw samples."""
        return (raw - self.b) @ self.matrix.T

    def invert(self, calibrated: np.ndarray) -> np.ndarray:
        """Raw samples that this model turns into ``calibrated`` (used by the generator)."""
        return np.linalg.solve(self.matrix, calibrated.T).T + self.b

    @staticmethod
    def mean(a: SensorModel, b: SensorModel) -> SensorModel:
        """Parameter-wise mean, for samples between two segments (method.md §2)."""
        return SensorModel(T=(a.T + b.T) / 2, K=(a.K + b.K) / 2, b=(a.b + b.b) / 2)


def acc_model(theta: np.ndarray) -> SensorModel:
    """M2 from the parameter vector ``(a_yz, a_zy, a_zx, s_x, s_y, s_z, b_x, b_y, b_z)``."""
    return SensorModel(T=acc_T(theta), K=np.array(theta[3:6], float), b=np.array(theta[6:9], float))


def acc_theta(model: SensorModel) -> np.ndarray:
    """The inverse of :func:`acc_model`."""
    T = model.T
    return np.array([-T[0, 1], T[0, 2], -T[1, 2], *model.K, *model.b])


def gyro_theta(model: SensorModel) -> np.ndarray:
    """M4's 6 misalignments and 3 scales of ``model`` (the fit's own mapping from parameters
    to a raw-unit model is :func:`imucal.stages.gyro_transitions.gyro_model_of`)."""
    T = model.T
    return np.array([T[0, 1], T[0, 2], T[1, 0], T[1, 2], T[2, 0], T[2, 1], *model.K])
