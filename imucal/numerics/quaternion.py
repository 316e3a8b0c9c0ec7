"""Unit quaternions as (..., 4) arrays ``(w, x, y, z)``, vectorised over leading axes.

A quaternion ``q`` here maps body-frame vectors to the reference frame: ``v_ref = R(q) v_body``.
With ``dq/dt = 1/2 q (x) (0, w)`` (w the body rate) that is the orientation of the body
relative to where it started (method.md M5).
"""

from __future__ import annotations

import numpy as np


def multiply(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product ``p (x) q``, broadcasting over leading axes."""
    pw, px, py, pz = np.moveaxis(p, -1, 0)
    qw, qx, qy, qz = np.moveaxis(q, -1, 0)
    return np.stack([
        pw * qw - px * qx - py * qy - pz * qz,
        pw * qx + px * qw + py * qz - pz * qy,
        pw * qy - px * qz + py * qw + pz * qx,
        pw * qz + px * qy - py * qx + pz * qw,
    ], axis=-1)


def conjugate(q: np.ndarray) -> np.ndarray:
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def normalize(q: np.ndarray) -> np.ndarray:
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def from_rotvec(v: np.ndarray) -> np.ndarray:
    """Quaternion of a rotation vector (axis times angle), exact for any angle."""
    v = np.asarray(v, float)
    angle = np.linalg.norm(v, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(a/2)/a -> 1/2 as a -> 0; use the series there to stay exact.
    with np.errstate(invalid="ignore", divide="ignore"):
        k = np.where(angle > 1e-8, np.sin(half) / np.where(angle > 0, angle, 1.0),
                     0.5 - angle * angle / 48.0)
    return np.concatenate([np.cos(half), v * k], axis=-1)


def to_rotvec(q: np.ndarray) -> np.ndarray:
    q = normalize(q)
    q = np.where(q[..., :1] < 0, -q, q)  # the shorter way round
    s = np.linalg.norm(q[..., 1:], axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, q[..., :1])
    with np.errstate(invalid="ignore", divide="ignore"):
        k = np.where(s > 1e-12, angle / np.where(s > 0, s, 1.0), 2.0)
    return q[..., 1:] * k


def to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix R(q), shape (..., 3, 3), for unit q."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], axis=-2)


def rotate_inverse(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``R(q)^T v``: a reference-frame vector seen in the body frame."""
    R = to_matrix(q)
    return np.einsum("...ji,...j->...i", R, v)


def random_unit(n: int, rng: np.random.Generator) -> np.ndarray:
    """Uniformly distributed rotations (normalised 4-D Gaussians)."""
    return normalize(rng.standard_normal((n, 4)))
