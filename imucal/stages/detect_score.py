"""The score of a set of still blocks, by which the detector's values are chosen (method.md
§1, §5): a cross-validated static norm error of block means, and the count of distinct
orientations it needs.

Each block is predicted by the accelerometer's block-mean fit (M2/M3 of accel.py, at a fixed
small lambda) made without it and without the other pieces of its hold: a hold cut in two
cannot predict itself, and a block that swallowed a turn is predicted badly (measured on a
synthetic session: cutting every hold in two raises the score from 0.16 to 0.28 mg, one
swallowed turn to 42 mg). imu_tk keeps the lowest in-sample residual, which both lower.
"""

from __future__ import annotations

import numpy as np

from imucal.errors import ImucalError
from imucal.models import ACC_THETA0
from imucal.numerics.directions import DISTINCT_ANGLE_DEG
from imucal.numerics.rows import floats
from imucal.numerics.windows import CHUNK_ROWS, block_means
from imucal.stages.accel import (
    FitPoints,
    best_fit,
    ellipsoid_start,
    jacobian,
    make_nominal,
    residuals,
)
from imucal.stages.detect import Candidate

MIN_ORIENTATIONS = 12  # 9 parameters, and some to spare for the cross-validation
TUNE_LAMBDA = 1e-4  # Tikhonov weight of the scoring fit (block means, nominal frame)
HOLD_ANGLE_DEG = 3.0  # consecutive blocks closer than this are pieces of one hold
GN_STEPS = 6  # Gauss-Newton steps of the scoring fit


class Prefix:
    """Running sums of a signal over bins of ``d`` samples, centred on the first sample (raw
    counts lose no digits): the sum over any run of bins in O(1). The scan's bins hold a few
    samples each, so the running sums are short and lose no digits either."""

    def __init__(self, x, d: int):
        n = len(x)
        self.d, self.origin = d, floats(x, 0, 1)[0].copy()
        edges = np.arange(0, n, d)
        # Whole bins a run at a time (each bin summed over its own samples, as on the whole
        # signal): no centred copy of the signal, which is read a slice at a time.
        sums = np.empty((len(edges),) + tuple(x.shape[1:]))
        step = max(1, CHUNK_ROWS // d) * d
        for a in range(0, n, step):
            b = min(a + step, n)
            sums[a // d:a // d + -(-(b - a) // d)] = np.add.reduceat(
                floats(x, a, b) - self.origin, np.arange(0, b - a, d), axis=0)
        self.s1 = np.concatenate([np.zeros((1, x.shape[1])), np.cumsum(sums, axis=0)])
        self.count = np.minimum(np.arange(len(edges) + 1) * d, n)


class Blocks:
    """Blocks ([start, end) sample indices), their lengths and raw mean vectors."""

    def __init__(self, blocks: np.ndarray, counts: np.ndarray, means: np.ndarray):
        self.blocks, self.counts, self.means = blocks, counts, means

    @classmethod
    def exact(cls, x, blocks: np.ndarray) -> Blocks:
        """``blocks`` in samples, their means summed over each block alone."""
        blocks = blocks.astype(np.int64).reshape(-1, 2)
        return cls(blocks, blocks[:, 1] - blocks[:, 0], block_means(x, blocks))

    @classmethod
    def of(cls, pre: Prefix, runs: np.ndarray) -> Blocks:
        """The blocks of ``runs`` in bins of ``pre``."""
        a, b = runs[:, 0], runs[:, 1]
        counts = (pre.count[b] - pre.count[a]).astype(np.int64)
        blocks = np.column_stack([pre.count[a], pre.count[b]]).astype(np.int64).reshape(-1, 2)
        means = (pre.s1[b] - pre.s1[a]) / np.maximum(counts, 1)[:, None] + pre.origin
        return cls(blocks, counts, means.reshape(-1, 3))


class Scorer:
    """Orientations and cross-validated score of a set of blocks, cached by the blocks."""

    def __init__(self, acc_unit: str, g_in: float):
        self.acc_unit, self.g_in = acc_unit, g_in
        self.cache: dict[bytes, tuple[int, float | None]] = {}

    def candidate(self, window: int, min_len: int, k: float, blk: Blocks, force: bool = False
                  ) -> Candidate:
        """The candidate's row; scored when it has MIN_ORIENTATIONS (or ``force``)."""
        key = blk.blocks.tobytes() + bytes([force])
        if key not in self.cache:
            self.cache[key] = self._score(blk, force)
        orient, score = self.cache[key]
        return Candidate(window, min_len, float(k), len(blk.blocks), orient, score)

    def _score(self, blk: Blocks, force: bool) -> tuple[int, float | None]:
        p = nominal_means(blk.means, self.acc_unit, self.g_in)
        if p is None:
            return min(len(blk.means), 1), None
        orient = count_directions(p)
        if orient < 2 or not (force or orient >= MIN_ORIENTATIONS):
            return orient, None
        return orient, loo_norm_error_mg(p, blk.counts / blk.counts.sum(), same_hold(p))


def nominal_means(means: np.ndarray, acc_unit: str, g_in: float) -> np.ndarray | None:
    """Block means in the accelerometer's nominal frame (accel.make_nominal: about its zero,
    |g| about 1); ``None`` where raw counts leave the zero unknown."""
    if len(means) < 4 and acc_unit == "counts":
        return None
    try:
        p = make_nominal(means, acc_unit, g_in).to_nominal(means)
    except ImucalError:
        return None
    if not np.all(np.isfinite(p)) or np.any(np.linalg.norm(p, axis=1) == 0):
        return None
    return p


def count_orientations(means: np.ndarray, acc_unit: str, g_in: float) -> int:
    """Distinct still directions (15 degrees apart) of block means, about the accelerometer's
    nominal zero (the sphere fit's centre for raw counts)."""
    p = nominal_means(means, acc_unit, g_in)
    return min(len(means), 1) if p is None else count_directions(p)


def count_directions(p: np.ndarray, min_angle_deg: float = DISTINCT_ANGLE_DEG,
                     block: int = 256) -> int:
    """:func:`imucal.numerics.directions.distinct_orientations`'s greedy count (a direction is
    kept unless within ``min_angle_deg`` of one kept before it): it runs on every candidate.
    The cosines are taken a block of directions at a time against those kept and against each
    other, never the whole (B, B) matrix (149 MB for the 4319 blocks of a 6-hour session)."""
    u = p / np.linalg.norm(p, axis=1, keepdims=True)
    c = np.cos(np.radians(min_angle_deg))
    kept: list[int] = []
    for a in range(0, len(u), block):
        ub = u[a:a + block]
        covered = np.zeros(len(ub), dtype=bool)
        if kept:
            covered |= (_cosines(ub, u[kept]) >= c).any(axis=1)
        near = _cosines(ub, ub) >= c
        rest = np.flatnonzero(~covered)
        while len(rest):
            i = int(rest[0])
            kept.append(a + i)
            covered |= near[i]
            rest = rest[1:][~covered[rest[1:]]]
    return len(kept)


def _cosines(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a @ b.T`` with the bits of the same entries of ``u @ u.T``: matrices of two rows or
    more (BLAS multiplies a single row by another routine, whose last bits differ)."""
    pa = a if len(a) > 1 else np.vstack([a, a])
    pb = b if len(b) > 1 else np.vstack([b, b])
    return (pa @ pb.T)[:len(a), :len(b)]


def same_hold(p: np.ndarray) -> np.ndarray:
    """Per block: does it continue the hold of the block before (its direction within
    HOLD_ANGLE_DEG)? Pieces of one cut hold, not a new pose."""
    u = p / np.linalg.norm(p, axis=1, keepdims=True)
    return np.r_[False, np.einsum("ij,ij->i", u[1:], u[:-1]) > np.cos(np.radians(HOLD_ANGLE_DEG))]


def loo_norm_error_mg(p: np.ndarray, w: np.ndarray, hold: np.ndarray,
                      lam: float = TUNE_LAMBDA) -> float | None:
    """Cross-validated static norm error (method.md §5) of block means ``p`` (nominal frame,
    |g| = 1), in mg: RMS over blocks, with weights ``w`` (their share of the samples), of
    ``1 - |T K (p_b - b)|`` predicted by the M3 fit without block b and the other pieces of
    its hold (``hold``: :func:`same_hold`), so a cut hold cannot predict itself.

    The M3 fit on all blocks is Gauss-Newton from accel.py's closed-form ellipsoid start (LM,
    accel.best_fit, where that does not settle); each left-out fit is one Gauss-Newton step
    from it (``theta_-G = theta + H_-G^-1 J_G' r_G``), exact for a linear model and close for
    this nearly linear one.
    """
    theta = _fit_block_means(p, lam)
    if theta is None:
        return None
    with np.errstate(all="ignore"):
        r = residuals(theta, p)
        J = jacobian(theta, p)
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(J))):
        return None
    first = np.flatnonzero(~hold)
    group = np.cumsum(~hold) - 1
    H = J.T @ J + lam * np.eye(J.shape[1])
    JJ = np.add.reduceat(J[:, :, None] * J[:, None, :], first, axis=0)
    Jr = np.add.reduceat(J * r[:, None], first, axis=0)
    try:
        step = np.linalg.solve(H[None] - JJ, Jr[..., None])[..., 0]
    except np.linalg.LinAlgError:
        return None
    r_cv = r + np.einsum("ij,ij->i", J, step[group])
    err = float(np.sqrt(np.sum(w * r_cv * r_cv))) * 1e3
    return err if np.isfinite(err) else None


def _fit_block_means(p: np.ndarray, lam: float) -> np.ndarray | None:
    """M3 on block means with Tikhonov ``lam``: a few Gauss-Newton steps from the ellipsoid
    start (the problem is nearly linear there); LM (accel.best_fit) if they do not settle."""
    theta = ellipsoid_start(p)
    if theta is not None and np.all(theta[3:6] > 0):
        eye = lam * np.eye(9)
        with np.errstate(all="ignore"):
            for _ in range(GN_STEPS):
                r = residuals(theta, p)
                J = jacobian(theta, p)
                g = J.T @ r + lam * (theta - ACC_THETA0)
                try:
                    step = np.linalg.solve(J.T @ J + eye, g)
                except np.linalg.LinAlgError:
                    break
                theta = theta - step
                if not np.all(np.isfinite(theta)):
                    break
                if np.max(np.abs(step)) < 1e-12:
                    return theta
    start = theta if theta is not None and np.all(np.isfinite(theta)) else ACC_THETA0.copy()
    try:
        report, _ = best_fit(FitPoints.plain(p), lam, {"start": start})
    except ImucalError:
        return None
    return report.theta
