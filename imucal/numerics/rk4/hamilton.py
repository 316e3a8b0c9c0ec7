"""The Hamilton product of quaternions held as four separate component arrays ``(w, x, y, z)``.

The RK4 scans work on component arrays (one contiguous array per component, any shape) rather
than on (..., 4) arrays: every operation then reads contiguous runs of values. Two forms of the
same product: :func:`mul`, elementwise on component tuples (fast for large arrays), and
:func:`mul_stacked`, one matrix product on (4, ...) arrays (fast for small ones, which are bound
by numpy's per-call overhead).
"""

from __future__ import annotations

import numpy as np

Vec = tuple[np.ndarray, np.ndarray, np.ndarray]
Quat = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def mul(p: Quat, q: Quat) -> Quat:
    """Hamilton product ``p (x) q`` of component arrays (fresh outputs, in-place accumulation)."""
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    w = pw * qw
    w -= px * qx
    w -= py * qy
    w -= pz * qz
    x = pw * qx
    x += px * qw
    x += py * qz
    x -= pz * qy
    y = pw * qy
    y -= px * qz
    y += py * qw
    y += pz * qx
    z = pw * qz
    z += px * qy
    z -= py * qx
    z += pz * qw
    return w, x, y, z


# p (x) q = H @ vec(p q'): the Hamilton product as a fixed linear map of the 16 products p_i q_j.
HAMILTON = np.zeros((4, 16))
for _i, _j, _k, _s in [(0, 0, 0, 1), (0, 1, 1, -1), (0, 2, 2, -1), (0, 3, 3, -1),
                       (1, 0, 1, 1), (1, 1, 0, 1), (1, 2, 3, 1), (1, 3, 2, -1),
                       (2, 0, 2, 1), (2, 1, 3, -1), (2, 2, 0, 1), (2, 3, 1, 1),
                       (3, 0, 3, 1), (3, 1, 2, 1), (3, 2, 1, -1), (3, 3, 0, 1)]:
    HAMILTON[_i, 4 * _j + _k] = _s


def mul_stacked(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product of stacked (4, ...) arrays, as one (4 x 16) matrix product."""
    prod = p[:, None] * q[None, :]
    return (HAMILTON @ prod.reshape(16, -1)).reshape(p.shape)
