"""The data of the accelerometer fit (method.md §3, M3): how still samples become fit points.

A still block is one orientation: its samples share one true vector. The default ("ml") fits
one residual per block, its mean, weighted by how well the mean is known and with the noise
bias of the norm removed; "mean" (plain block means), "chunks" (chunk means) and "thesis"
(thesis §3.2) remain as options.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from imucal.errors import ImucalError
from imucal.models import acc_T
from imucal.numerics.windows import centred_segment_sums, segment_sums

POINT_MODES = ("ml", "mean", "chunks", "thesis")


def select_points(acc: np.ndarray, blocks: np.ndarray, mode: str = "thesis", n_select: int = 99,
                  n_group: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """Low-noise fit points from each static block (thesis §3.2), vectorised over blocks.

    Returns the points (P, 3) and the index of the block each came from (P,). Averaging before
    the fit also shrinks the noise bias of the norm, ``E|a+n| ~ |a| + sigma^2/|a|`` (§3).
    "ml" and "mean" give one point per block, its mean; "ml" also weighs and bias-corrects
    them (:func:`ml_points`).
    """
    if len(blocks) == 0:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
    starts, ends = blocks[:, 0], blocks[:, 1]
    lengths = ends - starts
    if mode in ("ml", "mean"):
        pts = segment_sums(acc, starts, ends) / lengths[:, None]
        return pts, np.arange(len(blocks))
    if mode == "thesis":
        # n_select samples evenly spread over each block, then averaged in groups of n_group.
        frac = np.linspace(0.0, 1.0, n_select)
        idx = starts[:, None] + np.floor(frac[None, :] * (lengths[:, None] - 1)).astype(np.int64)
        samples = acc[idx]  # (B, n_select, 3)
        groups = np.array_split(np.arange(n_select), int(np.ceil(n_select / n_group)))
        pts = np.stack([samples[:, g].mean(axis=1) for g in groups], axis=1)  # (B, G, 3)
    elif mode == "chunks":
        n_chunks = n_group
        edges = starts[:, None] + (np.arange(n_chunks + 1)[None, :] * lengths[:, None]) // n_chunks
        sums = segment_sums(acc, edges[:, :-1].ravel(), edges[:, 1:].ravel()).reshape(
            len(blocks), n_chunks, 3)
        counts = (edges[:, 1:] - edges[:, :-1])[..., None]
        pts = np.where(counts > 0, sums / np.maximum(counts, 1), acc[0])
    else:
        raise ImucalError(f"unknown point selection {mode!r}; expected one of "
                          f"{', '.join(POINT_MODES)}", source="settings", field="points")
    g = pts.shape[1]
    return pts.reshape(-1, 3), np.repeat(np.arange(len(blocks)), g)


def residuals(theta: np.ndarray, pts: np.ndarray, target: np.ndarray | float = 1.0
              ) -> np.ndarray:
    """Data part of M3: ``r_i = t_i - |T K (a_i - b)|`` in the nominal frame, ``t_i = 1``
    (|g|) or the bias-corrected target of :func:`ml_points`."""
    y = (pts - theta[6:9]) * theta[3:6] @ acc_T(theta).T
    return target - np.sqrt(np.einsum("ij,ij->i", y, y))


def jacobian(theta: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Analytic d r / d theta of :func:`residuals` (r = t - |y|, y = T K (a - b))."""
    T = acc_T(theta)
    K = theta[3:6]
    v = pts - theta[6:9]
    u = v * K
    y = u @ T.T
    yh = y / np.linalg.norm(y, axis=1, keepdims=True)
    J = np.empty((len(pts), 9))
    J[:, 0] = yh[:, 0] * u[:, 1]  # dy/da_yz = (-u_y, 0, 0), dr = -yh . dy
    J[:, 1] = -yh[:, 0] * u[:, 2]  # dy/da_zy = (u_z, 0, 0)
    J[:, 2] = yh[:, 1] * u[:, 2]  # dy/da_zx = (0, -u_z, 0)
    yT = yh @ T  # yT[:, j] = yh . T[:, j]
    J[:, 3:6] = -yT * v  # dy/ds_j = T[:, j] v_j
    J[:, 6:9] = yT * K  # dy/db_j = -T[:, j] s_j
    return J


@dataclass(frozen=True)
class FitPoints:
    """The data of M3 in the nominal frame: points, their weights and their target norms.

    The fit minimises ``sum_i w_i^2 (t_i - |T K (p_i - b)|)^2 + lambda |theta - theta_0|^2``;
    the "thesis", "chunks" and "mean" points have ``w_i = t_i = 1``, "ml" those of
    :func:`ml_points`, which also records the noise model behind them.
    """

    pts: np.ndarray  # (P, 3)
    weight: np.ndarray  # (P,), mean of the squares 1
    target: np.ndarray  # (P,)
    white_var: np.ndarray | None = None  # (P,) white-noise variance of each norm residual
    excess_var: float = 0.0  # variance every block mean has beyond white noise (tau^2)

    @classmethod
    def plain(cls, pts: np.ndarray) -> FitPoints:
        return cls(pts, np.ones(len(pts)), np.ones(len(pts)))

    def residuals(self, theta: np.ndarray) -> np.ndarray:
        return self.weight * residuals(theta, self.pts, self.target)

    def jacobian(self, theta: np.ndarray) -> np.ndarray:
        return self.weight[:, None] * jacobian(theta, self.pts)


@dataclass(frozen=True)
class BlockNoise:
    """What each still block's own samples say about its noise, in the nominal frame."""

    n: np.ndarray  # (B,) samples per block
    var: np.ndarray  # (B, 3) per-axis sample variance

    @property
    def typical(self) -> np.ndarray:
        """Per-axis white-noise variance of the sensor, pooled over the blocks (each block's
        variance weighted by its degrees of freedom, ``n_k - 1``: unbiased, where a median of
        10-sample variances reads 7 % low). See :func:`ml_points` for why not each block's
        own. The static detector bounds every block's variance, so no moving block can
        dominate the pool. A noise-free signal (synthetic, or quantised to constant counts)
        has none: then every axis counts alike, which keeps the weights at ``sqrt(n_k)``."""
        dof = np.maximum(self.n - 1, 1)
        typ = dof @ self.var / dof.sum()
        top = float(typ.max()) if len(typ) else 0.0
        return np.maximum(typ, 1e-6 * top) if top > 0 else np.ones(3)


def block_scatter(acc: np.ndarray, blocks: np.ndarray) -> tuple[np.ndarray, BlockNoise]:
    """Mean (B, 3) of each still block, and its sample count and per-axis sample variance.

    One pass of sums of ``x`` and ``x^2`` over the blocks (no loop over blocks), centred first
    on the blocks' own centre so that ``E[x^2] - E[x]^2`` keeps the small variance of a still
    sensor (raw counts sit near 32768 with a noise of a few counts).
    """
    n = (blocks[:, 1] - blocks[:, 0]).astype(float)
    c = np.asarray(acc[blocks[:, 0]], float).mean(axis=0)
    s1, s2 = centred_segment_sums(acc, blocks[:, 0], blocks[:, 1], c)  # no copy of acc
    m1, m2 = s1 / n[:, None], s2 / n[:, None]
    var = np.clip(m2 - m1 * m1, 0, None) * (n / np.maximum(n - 1, 1))[:, None]  # unbiased
    return m1 + c, BlockNoise(n=n, var=var)


def ml_points(means: np.ndarray, noise: BlockNoise, theta_ref: np.ndarray,
              excess_var: float = 0.0) -> FitPoints:
    """The maximum-likelihood data of M3 (method.md §3): one residual per still block.

    A still block is one orientation: its ``n_k`` samples share one true vector, so its mean
    ``m_k`` (nominal frame) carries all it knows, with white-noise covariance ``V_k =
    diag(var) / n_k``. Through ``y = T K (m_k - b)`` (``M = T K``) only the radial part of that
    noise moves the norm, ``v_k = yh' M V_k M' yh`` (``sigma^2 / n_k`` for isotropic noise near
    nominal), so the ML weights are ``1 / sqrt(v_k)``, i.e. ``sqrt(n_k)``. A block mean can also
    carry an error that no averaging removes (drift, a model error, hand tremor): a variance
    ``tau^2`` (``excess_var``, from :func:`excess_variance`) common to every block, so the
    weights are ``1 / sqrt(v_k + tau^2)``: ``sqrt(n_k)`` for white noise, equal weights where
    the common error dominates.

    The weights are normalised to a mean square of 1: a factor common to all weights does not
    move the ``lambda = 0`` solution, and with ``sum w_k^2 = B`` the data weigh like one unit
    point per block, as in "mean" and in the grouping (which fits unweighted block means with
    lambda scaled by blocks / points, see pipeline.py). So a lambda means the same per block
    whatever the sample rate and hold durations; with raw ``sqrt(n_k)`` a session at 1000 Hz
    would weigh the prior ten times less than the same session at 100 Hz.

    ``var`` for the weights is the sensor's typical per-axis variance (pooled over blocks):
    one block's own, from a few hundred samples, is uncertain by 10 % or more, and a quiet
    block quantised to constant counts would show none and take all the weight. Blocks that
    do differ beyond white noise are what ``tau^2`` is for.

    The norm of a noisy mean is biased upwards: ``E|y + e| ~ |y| + (tr C_k - yh' C_k yh) /
    (2 |y|)`` with ``C_k = M V_k M'`` (here with the block's own variances), which for isotropic
    noise is the ``sigma^2 / (n_k |y|)`` of §3. The target norm of block k is therefore ``t_k =
    1 + beta_k``, with ``|y| = 1``, the target, in the denominator (a poor reference cannot
    then divide by a small norm). ``M`` and ``yh`` are taken at ``theta_ref``: ``beta_k`` is
    second order in the noise (1e-4 of |g| at the thesis's 10 % noise and 100 samples) and the
    reference moves it by a fraction of that, while fixed weights and targets keep the Jacobian
    exact and the costs of different starts comparable.
    """
    M = acc_T(theta_ref) * theta_ref[3:6][None, :]
    y = (means - theta_ref[6:9]) @ M.T
    norm = np.linalg.norm(y, axis=1, keepdims=True)
    yh = np.divide(y, norm, out=np.zeros_like(y), where=norm > 0)
    z2 = (yh @ M) ** 2  # (M' yh)^2, so yh' M diag(v) M' yh = sum_j z2_j v_j
    own = noise.var / noise.n[:, None]
    beta = 0.5 * (own @ (M * M).sum(axis=0) - np.einsum("bj,bj->b", z2, own))
    white = z2 @ noise.typical / noise.n
    w = 1.0 / np.sqrt(white + excess_var)
    w /= np.sqrt(np.mean(w * w))
    return FitPoints(pts=means, weight=w, target=1.0 + beta, white_var=white,
                     excess_var=float(excess_var))


def excess_variance(r: np.ndarray, white_var: np.ndarray, dof: float, z: float = 1.645) -> float:
    """The variance ``tau^2`` that block means share beyond white noise (Paule–Mandel).

    With residuals ``r_k`` of a fit with ``dof`` degrees of freedom left, white noise alone
    makes ``Q = sum r_k^2 / v_k`` a chi-square with ``dof`` degrees of freedom. While ``Q``
    stays below its upper ``z``-quantile (95 % by default; Wilson–Hilferty) the white-noise
    model stands and there is no excess: a fit that is what the noise model says keeps the
    ``sqrt(n_k)`` weights instead of chasing its own scatter (half of all white-noise fits
    have ``Q > dof``). Otherwise ``tau^2`` solves ``sum r_k^2 / (v_k + tau^2) = dof``: the sum
    falls monotonically in ``tau^2``, and bisection finds the root between 0 and
    ``sum r^2 / dof``.
    """
    r2 = np.asarray(r, float) ** 2
    v = np.asarray(white_var, float)
    if dof <= 0:
        return 0.0
    c = 2.0 / (9.0 * dof)
    if np.sum(r2 / v) <= dof * (1.0 - c + z * np.sqrt(c)) ** 3:
        return 0.0
    lo, hi = 0.0, float(np.sum(r2) / dof)
    for _ in range(60):  # relative precision 2^-60 of the bracket
        mid = 0.5 * (lo + hi)
        if np.sum(r2 / (v + mid)) > dof:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)
