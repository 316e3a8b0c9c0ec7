"""Several triads in one device (method.md §11): the rotation of each other accelerometer triad to
the reference's frame from the still blocks both saw (M12, M13), its standard error, and how well
the triads agree once calibrated (held-out blocks, in mg); for a flight log that calibrates
nothing, how far the IMUs disagree as logged.

Each triad's own calibration is the whole method run on its own samples (the pipeline does
that); this module only compares calibrated block means, so it knows nothing of M2's
parameters and works for triads on different clocks, rates and units.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from imucal.models import SensorModel, acc_model
from imucal.numerics import quaternion as quat
from imucal.numerics.windows import samples_within
from imucal.session import STANDARD_GRAVITY
from imucal.streams import Stream

# Fewest samples of a triad inside a reference block for its mean to count (method.md §11).
MIN_SAMPLES = 2
# PX4 refuses to arm when two accelerometers differ by more than this (COM_ARM_IMU_ACC).
PX4_ARM_ACC_M_S2 = 0.7


@dataclass(frozen=True)
class BlockMeans:
    """One triad's calibrated means inside the reference's still blocks (in units of |g|)."""

    means: np.ndarray  # (B, 3) mean / |g|
    var: np.ndarray  # (B,) variance of the mean, per axis (the axes' mean), in |g|^2
    counts: np.ndarray  # (B,) samples inside each block


def interval_means(t: np.ndarray, rows: Callable[[int, int], np.ndarray],
                   intervals: np.ndarray, g: float,
                   clipped: np.ndarray | None = None) -> BlockMeans:
    """The mean and the variance of the mean of ``rows(a, b)`` (calibrated samples) inside each
    closed time interval (method.md §11: the other triad averaged in the reference's blocks,
    whatever its clock). A block with fewer than :data:`MIN_SAMPLES` samples, or holding a
    sample of ``clipped`` (a (N,) mask of saturated samples), gets NaN."""
    idx = samples_within(t, intervals)
    b = len(idx)
    means = np.full((b, 3), np.nan)
    var = np.full(b, np.nan)
    counts = idx[:, 1] - idx[:, 0]
    bad = None
    if clipped is not None and clipped.any():
        csum = np.concatenate([[0], np.cumsum(clipped)])
        bad = csum[idx[:, 1]] - csum[idx[:, 0]] > 0
    for k, (lo, hi) in enumerate(idx):  # a loop over blocks, each a slice of samples
        if hi - lo < MIN_SAMPLES or (bad is not None and bad[k]):
            continue
        x = rows(int(lo), int(hi)) / g
        means[k] = x.mean(axis=0)
        var[k] = float(np.mean(x.var(axis=0, ddof=1))) / (hi - lo)
    return BlockMeans(means=means, var=var, counts=counts)


def kabsch(u: np.ndarray, v: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The rotation R minimising ``sum w_k |u_k - R v_k|^2`` (Wahba's problem by the SVD,
    its determinant forced to +1): the start of M13."""
    h = (u * w[:, None]).T @ v  # sum w_k u_k v_k'
    a, _, bt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(a @ bt)) or 1.0
    return a @ np.diag([1.0, 1.0, d]) @ bt


def _skew(v: np.ndarray) -> np.ndarray:
    """(B, 3, 3) cross-product matrices [v]x."""
    z = np.zeros(len(v))
    return np.stack([np.stack([z, -v[:, 2], v[:, 1]], -1),
                     np.stack([v[:, 2], z, -v[:, 0]], -1),
                     np.stack([-v[:, 1], v[:, 0], z], -1)], axis=1)


def _exp(delta: np.ndarray) -> np.ndarray:
    return quat.to_matrix(quat.from_rotvec(delta[None, :]))[0]


@dataclass(frozen=True)
class RotationFit:
    """M13 solved: the rotation taking the other triad's frame to the reference's, its
    covariance (rad^2, in the reference's frame) and the fit's chi-square."""

    R: np.ndarray  # (3, 3)
    cov: np.ndarray  # (3, 3) rad^2, scaled by the reduced chi-square where above 1
    chi2: float
    dof: int

    @property
    def std_deg(self) -> np.ndarray:
        """Standard error of the rotation about each reference axis, deg (inf where a triad's
        own fit leaves a parameter undetermined: not determined)."""
        return np.degrees(np.sqrt(np.diag(self.cov)))

    @property
    def std_total_deg(self) -> float:
        """The expected size of the rotation's error, ``sqrt(trace cov)``, deg."""
        with np.errstate(invalid="ignore"):
            return float(np.degrees(np.sqrt(np.trace(self.cov))))


def fit_rotation(u: np.ndarray, v: np.ndarray, s2: np.ndarray,
                 start: np.ndarray | None = None, iterations: int = 8,
                 empirical: bool = False) -> RotationFit:
    """``u_k = R v_k + e_k`` (M12) by Kabsch then Gauss–Newton on ``R = R_0 exp([delta]x)``
    (M13); the covariance ``c (J' W J)^-1`` from the Jacobian, ``c`` the reduced chi-square
    where it exceeds 1 (the triads' own calibration errors then count in it); ``empirical``:
    ``c`` the reduced chi-square whatever its size (``s2`` then only weighs the pairs)."""
    w = 1.0 / s2
    r0 = kabsch(u, v, w) if start is None else start
    jtwj = np.eye(3)
    for _ in range(iterations):
        res = u - v @ r0.T  # r_k = u_k - R v_k
        jac = r0[None] @ _skew(v)  # d r_k / d delta = R [v_k]x
        jtwj = np.einsum("k,kij,kil->jl", w, jac, jac)
        step = -np.linalg.solve(jtwj, np.einsum("k,kij,ki->j", w, jac, res))
        r0 = r0 @ _exp(step)
        if np.linalg.norm(step) < 1e-12:
            break
    res = u - v @ r0.T
    chi2 = float(np.sum(w * np.sum(res**2, axis=1)))
    dof = max(3 * len(u) - 3, 1)
    jac = r0[None] @ _skew(v)
    jtwj = np.einsum("k,kij,kil->jl", w, jac, jac)
    cov_body = np.linalg.inv(jtwj) * (chi2 / dof if empirical else max(1.0, chi2 / dof))
    # R exp([d]x) = exp([R d]x) R: the error about the reference's axes is R d.
    return RotationFit(R=r0, cov=r0 @ cov_body @ r0.T, chi2=chi2, dof=dof)


def angle_deg(r1: np.ndarray, r2: np.ndarray) -> float:
    """The angle of the rotation ``r1' r2``, deg."""
    c = (np.trace(r1.T @ r2) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


@dataclass(frozen=True)
class TriadAgreement:
    """Another accelerometer triad against the reference (method.md §11)."""

    rotation: RotationFit
    blocks: int  # shared still blocks used
    held_out_mg: np.ndarray  # (blocks,) |u_k - R_(-k) v_k| with block k held out, mg
    before_mg: np.ndarray  # (blocks,) |u_k - v_k| of the raw means in the nominal frame, mg
    used: np.ndarray  # (B,) True on the reference's blocks both triads saw
    # (blocks, 3) the calibrated means M12 was fitted to, in units of |g|: the reference's
    # (u) and the other triad's in its own frame (v); None where not kept.
    u: np.ndarray | None = None
    v: np.ndarray | None = None

    @property
    def after_mg(self) -> np.ndarray | None:
        """(blocks,) ``|u_k - R v_k|`` in mg: each block's gravity in both triads after
        calibration and the rotation (M12), in sample (:attr:`held_out_mg` holds block k out)."""
        if self.u is None or self.v is None:
            return None
        return np.linalg.norm(self.u - self.v @ self.rotation.R.T, axis=1) * 1e3

    @property
    def unrotated_mg(self) -> np.ndarray | None:
        """(blocks,) ``|u_k - v_k|`` in mg: calibrated, but each triad in its own frame (what
        the rotation between them costs where it is left out)."""
        if self.u is None or self.v is None:
            return None
        return np.linalg.norm(self.u - self.v, axis=1) * 1e3

    @property
    def held_out_rms_mg(self) -> float:
        return float(np.sqrt(np.mean(self.held_out_mg**2)))

    @property
    def before_rms_mg(self) -> float:
        return float(np.sqrt(np.mean(self.before_mg**2)))

    @property
    def angle_deg(self) -> float:
        """The rotation's angle, deg: how far the other triad's frame is turned."""
        return angle_deg(np.eye(3), self.rotation.R)


# Fewest shared blocks, in at least two directions, for a rotation (two determine it; a third
# leaves a residual to judge the fit by, and one to hold out).
MIN_SHARED_BLOCKS = 4


@dataclass(frozen=True)
class TriadModels:
    """One triad's accelerometer fits as the rotation's error sees them (method.md §11): its raw
    means inside the reference's blocks, each block's segment, and each segment's M2
    parameters (``ACC_PARAM_NAMES`` order, raw units) with their covariance."""

    raw_means: np.ndarray  # (B, 3) raw units
    segment_of_block: np.ndarray  # (B,) index into params / covs
    params: tuple[np.ndarray, ...]  # (9,) each
    covs: tuple[np.ndarray, ...]  # (9, 9) each
    g: float  # the calibrated output's |g|

    def means(self, params: tuple[np.ndarray, ...] | None = None) -> np.ndarray:
        """(B, 3) calibrated means / |g| through M2 with ``params`` (the fits' own if None)."""
        params = self.params if params is None else params
        out = np.empty_like(self.raw_means)
        for s, p in enumerate(params):
            on = self.segment_of_block == s
            out[on] = acc_model(p).apply(self.raw_means[on]) / self.g
        return out


def propagated_cov(models: TriadModels, which: int, u: np.ndarray, v: np.ndarray,
                   s2: np.ndarray, used: np.ndarray, R: np.ndarray) -> np.ndarray:
    """(3, 3) the rotation's covariance (rad^2, reference frame) from one triad's own M2
    errors: each parameter moved a little, the rotation refitted (M13), the change's Jacobian
    ``J`` and ``J C J'`` over the segments. ``which`` 0: the triad is the reference (``u``),
    1: the other (``v``)."""
    base = models.means()[used]
    out = np.zeros((3, 3))
    for s, (p, c) in enumerate(zip(models.params, models.covs)):
        if not np.any(models.segment_of_block[used] == s):
            continue
        if not np.all(np.isfinite(c)):  # a parameter the triad's data do not determine
            return np.full((3, 3), np.inf)
        jac = np.zeros((3, 9))
        for j in range(9):  # 9 small refits per segment, a loop over parameters
            eps = 1e-6 * max(1.0, abs(float(p[j])))
            moved = list(models.params)
            moved[s] = p.copy()
            moved[s][j] += eps
            d = models.means(tuple(moved))[used] - base
            uu, vv = (u + d, v) if which == 0 else (u, v + d)
            r2 = fit_rotation(uu, vv, s2, start=R, iterations=2).R
            dr = r2 @ R.T  # a small rotation: its axis-angle is its skew part, to first order
            jac[:, j] = np.array([dr[2, 1] - dr[1, 2], dr[0, 2] - dr[2, 0],
                                  dr[1, 0] - dr[0, 1]]) / (2 * eps)
        out += jac @ c @ jac.T
    return out


def triad_agreement(ref: BlockMeans, other: BlockMeans, ref_raw: np.ndarray,
                    other_raw: np.ndarray, ref_models: TriadModels | None = None,
                    other_models: TriadModels | None = None) -> TriadAgreement | None:
    """The rotation of ``other`` to ``ref`` (M12, M13) from the blocks both saw, and their
    held-out agreement; ``ref_raw``/``other_raw`` (B, 3) the raw means in each triad's nominal
    frame (|g|-normalised) for the figure before calibration. Given each triad's fits
    (``*_models``), the rotation's covariance holds their errors too (M2's frame moves with
    its misalignment angles, and the rotation with it). None where fewer than
    :data:`MIN_SHARED_BLOCKS` blocks are shared or they all point one way."""
    used = np.isfinite(ref.var) & np.isfinite(other.var)
    if used.sum() < MIN_SHARED_BLOCKS:
        return None
    u, v = ref.means[used], other.means[used]
    s2 = ref.var[used] + other.var[used]
    s2 = np.maximum(s2, 1e-18)  # a noiseless (synthetic) block still gets a finite weight
    if np.linalg.matrix_rank(u, tol=0.05) < 2:  # one direction: a turn about it is free
        return None
    fit = fit_rotation(u, v, s2)
    for k, models in enumerate((ref_models, other_models)):
        if models is not None:
            fit = dataclasses.replace(fit, cov=fit.cov + propagated_cov(
                models, k, u, v, s2, used, fit.R))
    n = len(u)
    held = np.empty(n)
    keep = np.ones(n, bool)
    for k in range(n):  # one small refit per block held out (a loop over blocks)
        keep[k] = False
        rk = fit_rotation(u[keep], v[keep], s2[keep], start=fit.R, iterations=3).R
        keep[k] = True
        held[k] = np.linalg.norm(u[k] - rk @ v[k]) * 1e3
    before = np.linalg.norm(ref_raw[used] - other_raw[used], axis=1) * 1e3
    return TriadAgreement(rotation=fit, blocks=n, held_out_mg=held, before_mg=before, used=used,
                          u=u, v=v)


# --- two clocks: the offset from the motion (method.md §11) -------------------------------------

ENVELOPE_STEP_S = 0.01  # the grid the two motions are compared on
ENVELOPE_SMOOTH_S = 0.1
MAX_OFFSET_S = 5.0
ENVELOPE_ROWS = 1 << 18  # samples read at once


def motion_envelope(t: np.ndarray, x: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """(G,) how fast the direction of ``x`` turns on ``grid`` (rad/s): the unit vectors
    averaged over each grid cell (every sample counts once: no aliasing of the noise), then
    the central difference over ``ENVELOPE_SMOOTH_S``. The same in every triad's frame,
    whatever its scale and bias errors to first order, and zero in still poses."""
    g = len(grid)
    sums, n = np.zeros((g, 3)), np.zeros(g)
    for lo in range(0, len(t), ENVELOPE_ROWS):  # a chunk of rows at a time: no N x 3 temporary
        tc, xc = t[lo:lo + ENVELOPE_ROWS], np.asarray(x[lo:lo + ENVELOPE_ROWS], float)
        cell = np.searchsorted(grid, tc, side="right") - 1
        inside = (cell >= 0) & (tc < grid[-1] + (grid[-1] - grid[-2]))
        cell, xc = cell[inside], xc[inside]
        u = xc / np.linalg.norm(xc, axis=1, keepdims=True)
        n += np.bincount(cell, minlength=g)
        for i in range(3):
            sums[:, i] += np.bincount(cell, weights=u[:, i], minlength=g)
    cells = sums / np.maximum(n, 1)[:, None]
    empty = n == 0  # a cell without a sample (a slower triad): its neighbours' value
    if empty.any():
        for i in range(3):
            cells[empty, i] = np.interp(grid[empty], grid[~empty], cells[~empty, i])
    h = max(int(round(ENVELOPE_SMOOTH_S / 2 / ENVELOPE_STEP_S)), 1)
    rate = np.zeros(len(grid))
    rate[h:-h] = np.linalg.norm(cells[2 * h:] - cells[:-2 * h], axis=1) / (2 * h * ENVELOPE_STEP_S)
    return rate


def clock_offset(t_ref: np.ndarray, x_ref: np.ndarray, t_other: np.ndarray,
                 x_other: np.ndarray, max_lag: float = MAX_OFFSET_S) -> tuple[float, float]:
    """How far the other triad's clock reads ahead of the reference's (s; subtract it from
    its times), and the normalised correlation at that lag: the two motion envelopes
    (:func:`motion_envelope`) cross-correlated by FFT over lags within ``max_lag``, the peak
    refined by a parabola. (nan, 0) where the clocks share less than 4 ``max_lag``."""
    lo, hi = max(t_ref[0], t_other[0]), min(t_ref[-1], t_other[-1])
    if hi - lo < 4 * max_lag:
        return float("nan"), 0.0
    grid = np.arange(lo, hi, ENVELOPE_STEP_S)
    a = motion_envelope(t_ref, x_ref, grid)
    b = motion_envelope(t_other, x_other, grid)
    a, b = a - a.mean(), b - b.mean()
    n = len(a)
    size = 1 << int(np.ceil(np.log2(2 * n)))
    corr = np.fft.irfft(np.conj(np.fft.rfft(a, size)) * np.fft.rfft(b, size), size)
    lag = int(round(max_lag / ENVELOPE_STEP_S))
    lags = np.r_[np.arange(0, lag + 1), np.arange(-lag, 0)]
    c = corr[lags]
    k = int(np.argmax(c))
    shift = float(lags[k])
    if 0 < k < len(c) - 1 and lags[k - 1] == lags[k] - 1 and lags[(k + 1) % len(c)] == lags[k] + 1:
        y0, y1, y2 = c[k - 1], c[k], c[k + 1]
        den = y0 - 2 * y1 + y2
        if den < 0:
            shift += 0.5 * (y0 - y2) / den
    norm = float(np.sqrt(np.sum(a**2) * np.sum(b**2)))
    return shift * ENVELOPE_STEP_S, float(c[k] / norm) if norm > 0 else 0.0


# --- a triad calibrated against the reference (method.md §11, M15) ------------------------------


@dataclass(frozen=True)
class AgainstReference:
    """Another triad's M2 and rotation fitted to the reference's calibrated gravity vectors
    (M15): three equations per still block where its own fit (M3) has one, so a noisy
    (high-range) triad is pinned to the precise one; the reference's own errors pass into it."""

    model: SensorModel  # M2 in the triad's raw unit, output in units of |g|
    R: np.ndarray  # (3, 3) its frame to the reference's
    std_K: np.ndarray  # (3,) standard errors of the scales
    std_b: np.ndarray  # (3,) standard errors of the bias, raw unit
    rms_mg: float  # the fit's residual, mg
    blocks: int


def _split_affine(A: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, SensorModel]:
    """``A m + c = R T K (m - b)``: R from the QR decomposition of A (upper triangular factor
    with a positive diagonal, M2's T K), then K its diagonal, T its columns over K, b."""
    q, u = np.linalg.qr(A)
    sign = np.sign(np.diag(u))
    sign[sign == 0] = 1.0
    q, u = q * sign[None, :], u * sign[:, None]
    if np.linalg.det(q) < 0:  # a reflection is no rotation: A itself is improper
        raise ValueError("the affine map reflects: no rotation and M2 give it")
    K = np.diag(u).copy()
    return q, SensorModel(T=u / K[None, :], K=K, b=-np.linalg.solve(A, c))


def fit_against_reference(u: np.ndarray, m: np.ndarray, s2: np.ndarray
                          ) -> AgainstReference | None:
    """M15 by weighted linear least squares on ``u_k = A m_k + c`` (``u`` (B, 3) the
    reference's calibrated means over |g|, ``m`` the triad's raw means, ``s2`` each block's
    variance), then split into R and M2; the covariance of K and b from the least squares
    (scaled by the residuals' reduced chi-square where above 1) through the split's Jacobian.
    None with fewer than 6 blocks."""
    b = len(u)
    if b < 6:
        return None
    w = 1.0 / np.sqrt(s2)
    X = np.hstack([m, np.ones((b, 1))]) * w[:, None]  # one row per block, the same per axis
    coef, *_ = np.linalg.lstsq(X, u * w[:, None], rcond=None)  # (4, 3): [A'; c']
    res = u * w[:, None] - X @ coef
    dof = max(3 * b - 12, 1)
    scale = max(1.0, float(np.sum(res**2)) / dof)
    xtx_inv = np.linalg.inv(X.T @ X) * scale  # each output axis: the same design
    A, c = coef[:3].T, coef[3]
    R, model = _split_affine(A, c)

    def parts(p: np.ndarray) -> np.ndarray:
        _, mm = _split_affine(p[:9].reshape(3, 3), p[9:])
        return np.r_[mm.K, mm.b]

    p0 = np.r_[A.ravel(), c]
    cov_p = np.zeros((12, 12))  # A row i and c_i come from output axis i's regression
    for i in range(3):
        idx = [3 * i, 3 * i + 1, 3 * i + 2, 9 + i]
        cov_p[np.ix_(idx, idx)] = xtx_inv
    jac = np.empty((6, 12))
    for j in range(12):  # the split's Jacobian by central differences (12 small QRs)
        h = 1e-7 * max(1.0, abs(p0[j]))
        up, dn = p0.copy(), p0.copy()
        up[j] += h
        dn[j] -= h
        jac[:, j] = (parts(up) - parts(dn)) / (2 * h)
    cov = jac @ cov_p @ jac.T
    std = np.sqrt(np.diag(cov))
    rms = float(np.sqrt(np.mean(np.sum((u - m @ A.T - c) ** 2, axis=1)))) * 1e3
    return AgainstReference(model=model, R=R, std_K=std[:3], std_b=std[3:], rms_mg=rms,
                            blocks=b)


# --- gyroscopes: the rotation from the turns (method.md §11, M14) --------------------------------

# Turns smaller than this say little about an axis (their rotation vector is mostly noise).
MIN_TURN_DEG = 10.0


@dataclass(frozen=True)
class GyroAgreement:
    """Another gyroscope against the reference's, from the turns both measured (M14)."""

    rotation: RotationFit
    turns: int  # turns used
    residual_deg: np.ndarray  # (turns,) |r_ref - R r_other| per turn, deg
    accel_difference_deg: float | None  # angle between this and its IMU's accelerometer's

    @property
    def residual_rms_deg(self) -> float:
        return float(np.sqrt(np.mean(self.residual_deg**2)))


def turn_rotvecs(x: np.ndarray, t: np.ndarray, block_times: np.ndarray, M: np.ndarray,
                 b: np.ndarray) -> np.ndarray:
    """(K, 3) each turn's rotation vector (rad): the calibrated rates ``M[k] (x - b[k])`` (M4,
    each turn its own model, ``M`` (K, 3, 3), ``b`` (K, 3)) integrated by RK4 from the end of
    still block k to the start of block k+1 on the gyroscope's own clock."""
    from imucal.numerics.rk4.intervals import Intervals
    from imucal.stages.gyro_transitions import transition_samples

    s, e = transition_samples(t, block_times)
    q = Intervals(x, t, s, e).integrate_each(M, b)
    return quat.to_rotvec(q)


def gyro_model_from(p: np.ndarray, b: np.ndarray) -> SensorModel:
    """The M4 model of :func:`imucal.models.gyro_theta`'s 9 numbers (T's off-diagonals row by
    row, then K) and a bias."""
    T = np.eye(3)
    T[0, 1], T[0, 2], T[1, 0], T[1, 2], T[2, 0], T[2, 1] = p[:6]
    return SensorModel(T=T, K=np.asarray(p[6:9], float), b=np.asarray(b, float))


@dataclass(frozen=True)
class GyroTurns:
    """One triad's gyroscope as M14 sees it: ``turns(s, p)`` the (K, 3) turn rotation vectors
    with segment ``s``'s 9 parameters replaced by ``p`` (None, None: the fit's own), and each
    segment's parameters and their standard errors (raw units)."""

    turns: Callable[[int | None, np.ndarray | None], np.ndarray]
    params: tuple[np.ndarray, ...]
    stds: tuple[np.ndarray, ...]


def _propagated_turn_cov(g: GyroTurns, which: int, u: np.ndarray, v: np.ndarray,
                         ok: np.ndarray, R: np.ndarray) -> np.ndarray:
    """(3, 3) the rotation's covariance from one gyroscope's own M4 errors: each parameter
    moved a little, the turns integrated again and M14 refitted (their standard errors only:
    the fit reports no correlations)."""
    base = g.turns(None, None)[ok]
    out = np.zeros((3, 3))
    for s, (p, sd) in enumerate(zip(g.params, g.stds)):
        if not np.all(np.isfinite(sd)):  # a parameter the gyroscope's data do not determine
            return np.full((3, 3), np.inf)
        jac = np.zeros((3, 9))
        for j in range(9):  # 9 integrations of the turns per segment, a loop over parameters
            eps = 1e-6 * max(1.0, abs(float(p[j])))
            moved = p.copy()
            moved[j] += eps
            d = g.turns(s, moved)[ok] - base
            uu, vv = (u + d, v) if which == 0 else (u, v + d)
            r2 = fit_rotation(uu, vv, np.ones(len(u)), start=R, iterations=2).R
            dr = r2 @ R.T
            jac[:, j] = np.array([dr[2, 1] - dr[1, 2], dr[0, 2] - dr[2, 0],
                                  dr[1, 0] - dr[0, 1]]) / (2 * eps)
        out += jac @ np.diag(sd**2) @ jac.T
    return out


def gyro_agreement(ref: GyroTurns, other: GyroTurns,
                   accel_R: np.ndarray | None = None) -> GyroAgreement | None:
    """``r_ref,k = R r_other,k`` (M14) over the turns of at least :data:`MIN_TURN_DEG` in both
    by Kabsch and Gauss–Newton (:func:`fit_rotation`); the covariance from the residuals'
    scatter and each gyroscope's own M4 errors. None with fewer than
    :data:`MIN_SHARED_BLOCKS` turns in two directions."""
    r_ref, r_other = ref.turns(None, None), other.turns(None, None)
    big = np.radians(MIN_TURN_DEG)
    ok = (np.linalg.norm(r_ref, axis=1) > big) & (np.linalg.norm(r_other, axis=1) > big)
    u, v = r_ref[ok], r_other[ok]
    if len(u) < MIN_SHARED_BLOCKS or np.linalg.matrix_rank(u, tol=0.05 * big) < 2:
        return None
    fit = fit_rotation(u, v, np.ones(len(u)), empirical=True)
    for k, g in enumerate((ref, other)):
        fit = dataclasses.replace(fit, cov=fit.cov + _propagated_turn_cov(g, k, u, v, ok, fit.R))
    res = np.degrees(np.linalg.norm(u - v @ fit.R.T, axis=1))
    diff = None if accel_R is None else angle_deg(fit.R, accel_R)
    return GyroAgreement(rotation=fit, turns=len(u), residual_deg=res,
                         accel_difference_deg=diff)


# --- a log that calibrates nothing: the IMUs as logged ------------------------------------------


@dataclass(frozen=True)
class LoggedImu:
    """One accelerometer of a log as logged: its mean, temperature, and difference to the
    reference's over the time both cover (method.md §11, a flight log)."""

    name: str
    samples: int
    mean: np.ndarray  # (3,) mean accelerometer vector, in the stream's unit
    unit: str | None
    temperature: float | None  # mean deg C, where the log has its temperature
    difference: float | None  # |mean - reference's mean| over the shared time, stream's unit
    shared_s: float  # the time both cover, s
    frame: str | None = None  # the axis convention the log states for it


def logged_imus(accs: Sequence[Stream], temps: Sequence[Stream]) -> list[LoggedImu]:
    """Each accelerometer stream against the first (the reference, method.md §11 on a flight
    log): the means over the time both cover and their difference, and each one's mean
    temperature (a temperature stream of the same IMU, or of the same instance). A triad in g
    against one in m/s² is converted to the reference's unit."""
    ref = accs[0]
    out = []
    for acc in accs:
        temp = [t for t in temps if t.instance == acc.instance
                or (acc.imu is not None and t.imu == acc.imu)]
        tmean = float(np.mean(temp[0].values)) if temp and temp[0].samples else None
        lo, hi = max(ref.t[0], acc.t[0]), min(ref.t[-1], acc.t[-1])
        mine = (acc.t >= lo) & (acc.t <= hi)
        theirs = (ref.t >= lo) & (ref.t <= hi)
        diff, span = None, max(0.0, float(hi - lo))
        if acc is ref:
            diff = 0.0
        elif mine.any() and theirs.any():
            scale = 1.0
            if {acc.unit, ref.unit} == {"g", "m/s^2"}:
                scale = STANDARD_GRAVITY if ref.unit == "m/s^2" else 1.0 / STANDARD_GRAVITY
            diff = float(np.linalg.norm(acc.values[mine].mean(axis=0) * scale
                                        - ref.values[theirs].mean(axis=0)))
        out.append(LoggedImu(name=acc.name, samples=acc.samples, mean=acc.values.mean(axis=0),
                             unit=acc.unit, temperature=tmean, difference=diff, shared_s=span,
                             frame=acc.frame))
    return out


def logged_lines(imus: list[LoggedImu]) -> list[str]:
    """The IMUs as logged, one line each, and why that is all a log of this kind can say."""
    ref = imus[0]
    out = [f"{len(imus)} accelerometers as logged, against {ref.name} (no calibration: a "
           "recording without still poses in many orientations, a flight, cannot calibrate "
           "them; record one and run imucal calibrate --all-imus)"]
    for imu in imus:
        unit = imu.unit or "raw"
        temp = "" if imu.temperature is None else f", {imu.temperature:.1f} degC"
        if imu is ref:
            diff = "the reference"
        elif imu.difference is None:
            diff = "no time shared with the reference"
        else:
            arm = ""
            if imu.unit in ("m/s^2", "g"):
                limit = PX4_ARM_ACC_M_S2 / (STANDARD_GRAVITY if imu.unit == "g" else 1.0)
                arm = (" (above PX4's 0.7 m/s^2 arming limit)" if imu.difference > limit
                       else " (within PX4's 0.7 m/s^2 arming limit)")
            diff = (f"differs from the reference by {imu.difference:.3g} {ref.unit or 'raw'} "
                    f"over {imu.shared_s:.1f} s{arm}")
            if imu.frame != ref.frame:  # a rotated frame differs by more than its errors
                diff += f"; stated in another frame ({imu.frame or 'none stated'})"
        mean = ", ".join(f"{v:.3f}" for v in imu.mean)
        out.append(f"{imu.name}: {imu.samples} samples, mean ({mean}) {unit}{temp}; {diff}")
    return out
