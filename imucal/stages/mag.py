"""The magnetometer: hard and soft iron, and its rotation to the accelerometer (model M8).

Model M8 (docs/method.md §9)::

    m = R_am M (m_raw - b),        |m| = F,        u . m / F = -sin(dip)  (still)

``b`` (3) is the hard iron in the raw unit; ``M`` (3x3, symmetric, ``det M = 1``) the soft
iron, scale and non-orthogonality; ``F`` the local field's norm in the raw unit (``det M = 1``
keeps the calibrated field in the raw unit: ``M`` changes its shape, never its volume);
``R_am`` (a rotation, 3 parameters) takes the magnetometer's corrected frame to the
accelerometer's calibrated frame (M2's); ``dip`` is the angle of the field below the horizon
(positive in the northern hemisphere) and ``u`` the calibrated accelerometer's unit "up" (the
specific force of a still sensor).

The fit works on ``G = M / F`` (6 free entries) and ``b``: ``|G (m_raw - b)| = 1`` is a
non-degenerate parametrisation of the ellipsoid, and ``F = det(G)^(-1/3)``, ``M = F G`` follow
(their standard errors by the delta method).

Estimation, in order:

1. a closed-form algebraic ellipsoid fit of every sample (no hand-set guess, any unit:
   :func:`imucal.numerics.ellipsoid.algebraic_fit`), refined by maximum likelihood on every
   sample (still or not): residual ``|G (m_raw - b)| - 1``, for the search below; the fit
   returned is maximum likelihood with the shape held towards a sphere by a Tikhonov term,
   lambda at the L-curve's corner (M8r, :mod:`imucal.numerics.ellipsoid_tikhonov`): negligible
   where the directions determine the soft iron, the sphere's pull where they do not; the
   standard errors reported are the data's alone, none where past UNDETERMINED_STD;
2. a field that is not constant (a magnet nearby or carried along, a steel table) is found and
   left out: a step of the field inside a still block (the sensor did not turn, the field
   moved); windows whose mean norm residual departs from the others' by far more than their
   spread, judged first by a robust fit (Cauchy loss) and then by the plain fit of the rest
   until the windows left out stop changing; a still block whose dip departs from the others';
   when what is left reaches too few field directions to determine an ellipsoid, the
   magnetometer is not calibrated (:class:`MagUnfit` says why and what was found);
3. ``R_am`` and the dip from the still blocks of the accelerometer's calibration: the
   magnetometer's samples inside each block's time interval (its own clock) averaged to
   ``h_k``, then ``u_k . R_am h_k = -sin(dip)`` solved in closed form (linear in the nine
   entries of ``R_am`` and ``sin dip``, projected on the rotations) and refined with the
   ellipsoid held at the samples' fit; the standard errors: the ellipsoid's from the samples'
   Jacobian, ``R_am``'s and the dip's from the blocks' spread with the ellipsoid's errors
   carried through (a joint fit of samples and blocks lets the blocks pull the ellipsoid, and
   with them the accelerometer's own calibration errors, which are in no covariance here: its
   standard errors of b came out 1.9x too small through the whole pipeline, 20 seeds);
4. quality: the norm residual in % of the field in-sample and held out (fit on one half of the
   recording's time, judged on the other, and back), the dip spread over the still blocks,
   the fraction of field directions covered and, when short, the direction missing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from imucal.numerics import quaternion as quat
from imucal.numerics.ellipsoid import (
    EllipsoidFit,
    fit_ellipsoid,
    is_ellipsoid,
    sphere_coverage,
    sphere_fit,
    sym_from_vec,
    vec_from_sym,
)
from imucal.numerics.ellipsoid_tikhonov import RegularisedFit, regularised_fit
from imucal.numerics.windows import runs_of_true, samples_within
from imucal.stages.accel import LCurve
from imucal.stages.accel_cv import axis_words
from imucal.stages.mag_align import (
    MIN_BLOCKS_WITH_TURNS,
    MIN_TURNS,
    Alignment,
    Turns,
    closed_form,
    fit_with_turns,
)
from imucal.stages.mag_align import rotation as _rotation
from imucal.stages.mag_align import unit as _unit
from imucal.streams import Stream
from imucal.warning import RunWarning

# Samples the maximum-likelihood fit uses at most (every k-th beyond): 100 000 give standard
# errors of 1e-4 of the field, far below what a magnetometer's model error leaves.
MAX_FIT_SAMPLES = 100_000
# ... and the search for disturbed parts, which fits again and again, at most this many.
MAX_SEARCH_SAMPLES = 20_000
# Below this fraction of the sphere's directions reached, no ellipsoid is determined; a
# sphere (hard iron and field, 4 parameters) down to MIN_SPHERE_COVERAGE.
MIN_COVERAGE = 0.25
MIN_SPHERE_COVERAGE = 0.1
# Disturbance windows: at least 1 s and 25 samples; a window departs when its mean norm
# residual is farther from the windows' median than DISTURB_K robust standard deviations of
# the windows' means and than DISTURB_FLOOR of the field.
WINDOW_S = 1.0
WINDOW_MIN_SAMPLES = 25
DISTURB_K = 8.0
DISTURB_FLOOR = 0.005
# A step of the field inside a still block: this many noise standard deviations of the two
# levels' difference (the best split of white noise rarely reaches 4), and more than
# STEP_FLOOR of the field's scale.
STEP_Z = 30.0
STEP_FLOOR = 0.03
# A still block's dip departs when it is farther from the blocks' median than DIP_K robust
# standard deviations and DIP_FLOOR_DEG.
DIP_K = 6.0
DIP_FLOOR_DEG = 0.5
MIN_BLOCK_SAMPLES = 3
# Still blocks with magnetometer samples that R_am and the dip need from them alone: M8's closed
# form has ten unknowns (R_am's nine entries and sin(dip)); with six to nine blocks its null
# space has several dimensions, and the refinement started in it landed 117-176 deg from the
# truth (or the dip 50 deg off) on 6 of 12 synthetic sessions tried with 6 or 8 blocks
# (tests/stages/test_mag_turns.py).
MIN_BLOCKS = 10
# A soft-iron entry, or the hard iron or field over the field, whose data-alone standard error
# (M8r) exceeds this is not determined by the recording: held near the prior, no error given
# (1 % of the field turns a calibrated direction by up to 0.6 deg).
UNDETERMINED_STD = 0.01
COVERAGE_ANGLE_DEG = 15.0  # a field direction is covered by a sample within this angle
GOOD_COVERAGE = 0.9


@dataclass(frozen=True)
class MagDisturbance:
    """A part of the recording where the field was not the rest's, ``[t_start, t_end]`` (s):
    ``kind`` "norm" (the calibrated norm departs from the field by ``size`` typically and
    ``peak`` at most, % of the field), "dip" (a still block's dip departs by ``size``
    degrees) or "step" (the raw field stepped by ``size`` raw units inside a still block at
    ``t_start``, the sensor not turning: the block's rest, to ``t_end``, is left out)."""

    t_start: float
    t_end: float
    kind: str
    size: float
    peak: float
    unit: str  # of size and peak: "%" of the field, "deg", or the raw unit

    def text(self) -> str:
        if self.kind == "step":
            return (f"at {self.t_start:.1f} s the field stepped by {self.size:.3g} {self.unit} "
                    "while the sensor was still (a magnet or iron moved near it)")
        if self.kind == "dip":
            return (f"{self.t_start:.1f}-{self.t_end:.1f} s (a still block's dip off by "
                    f"{self.size:.2g} deg)")
        return (f"{self.t_start:.1f}-{self.t_end:.1f} s (norm off by {self.size:.2g} % "
                f"typically, {self.peak:.2g} % at most)")

    def to_dict(self) -> dict:
        return {"t_start": self.t_start, "t_end": self.t_end, "kind": self.kind,
                "size": self.size, "peak": self.peak, "unit": self.unit}


@dataclass(frozen=True)
class MagQuality:
    """The figures a user reads first (§5's, for the magnetometer)."""

    norm_rms_pct: float  # |m| / F - 1, RMS over the samples used, %
    norm_rms_held_out_pct: float | None  # the same, each half judged by the other's fit
    dip_spread_deg: float | None  # standard deviation of the still blocks' dip
    coverage: float  # fraction of the sphere's directions the field reached
    missing: str | None  # the direction not reached, in plain words; None: coverage is good
    blocks: int  # still blocks R_am and the dip were fitted on
    # the heading's standard error that the parameters' covariance predicts, RMS over the
    # still poses (deg); None without R_am
    heading_std_deg: float | None = None


@dataclass(frozen=True)
class MagFit:
    """M8 fitted, in the raw unit, with the standard errors of every parameter.

    ``R_am`` is None (and ``dip_deg``) when fewer than MIN_BLOCKS still blocks hold
    magnetometer samples. ``std_R_am_deg`` are the standard errors of the small rotation
    ``R_am <- exp([d]x) R_am`` about the accelerometer's x, y, z axes, degrees.
    ``cov`` is the covariance of ``(g11, g12, g13, g22, g23, g33, b, d, dip)`` (13) or of the
    first 9 without ``R_am``, ``G = M / F``."""

    M: np.ndarray
    b: np.ndarray
    field: float
    R_am: np.ndarray | None
    dip_deg: float | None
    std_M: np.ndarray
    std_b: np.ndarray
    std_field: float
    std_R_am_deg: np.ndarray | None
    std_dip_deg: float | None
    cov: np.ndarray
    unit: str | None
    stream: str  # the stream's name ("mag compassBuffer")
    samples: int  # the stream's samples
    used: np.ndarray  # (N,) True on the samples the fit used (not disturbed)
    start: str  # the algebraic start: "ellipsoid" or "sphere"
    disturbances: tuple[MagDisturbance, ...]
    quality: MagQuality
    block_dip_deg: np.ndarray  # (B,) each still block's dip, NaN where it has no samples
    block_used: np.ndarray  # (B,) True where the block took part in R_am and the dip
    warnings: tuple[RunWarning, ...] = ()
    # False: too few field directions for the ellipsoid; M held at the identity, b and the
    # field fitted (a sphere)
    soft_iron: bool = True
    # (B, 2) [t_start, t_end] (s) of the still blocks that block_dip_deg and block_used follow
    # (the stream's clock); None when no blocks were given
    block_times: np.ndarray | None = None
    # what determined R_am: the still blocks, the gyroscope's turns or both (None without R_am)
    alignment: Alignment | None = None
    # the factor by which the residual's correlation along the recording scales the
    # ellipsoid's covariance over what independent samples would give (method.md §9; about 1
    # for white noise, 70-360 on the shared real recordings), and the block length of the
    # jackknife that measured it (s: the fit's points in it times their mean spacing)
    se_design_effect: float = 1.0
    se_block_s: float = 0.0
    # M8r: the L-curve of the shape's Tikhonov term (thetas: (L, 9) g11..g33, b in the raw
    # unit; residual_norm the RMS norm residual in the raw unit; solution_norm |M / (tr M /
    # 3) - I|_F) and the lambda chosen; the parameters the data leave open (UNDETERMINED_STD)
    lcurve: LCurve | None = None
    lam: float | None = None
    undetermined: tuple[str, ...] = ()

    @property
    def G(self) -> np.ndarray:
        return self.M / self.field

    def ellipsoid(self, u: np.ndarray) -> np.ndarray:
        """The fitted ellipsoid in the raw frame: the raw field ``b + F M^-1 u`` (K, 3) whose
        calibrated norm is the field (M8: ``|M (m_raw - b)| = F``) at the unit directions
        ``u`` (K, 3) of the magnetometer's corrected frame."""
        return self.b + self.field * np.linalg.solve(self.M, np.asarray(u, float).T).T

    def apply(self, raw: np.ndarray) -> np.ndarray:
        """Calibrated field (N, 3) in the raw unit, in the accelerometer's calibrated frame
        (the magnetometer's corrected frame without ``R_am``)."""
        m = (np.asarray(raw, float) - self.b) @ self.M.T
        return m if self.R_am is None else m @ self.R_am.T

    def norm_error(self, raw: np.ndarray) -> np.ndarray:
        """``|M (m_raw - b)| / F - 1`` for (N, 3) raw samples."""
        return np.linalg.norm((np.asarray(raw, float) - self.b) @ self.G.T, axis=1) - 1.0


def _window_index(t: np.ndarray) -> tuple[np.ndarray, float]:
    steps = np.diff(t)
    step = float(np.median(steps)) if len(steps) else 1.0
    width = max(WINDOW_S, WINDOW_MIN_SAMPLES * step)
    return ((t - t[0]) // width).astype(np.int64), width


def _subsample(x: np.ndarray, most: int = MAX_FIT_SAMPLES) -> np.ndarray:
    return x[::max(1, -(-len(x) // most))]


class MagUnfit(Exception):
    """The magnetometer cannot be calibrated from this recording: ``message`` says why, and
    ``disturbances`` what was found on the way (said even so)."""

    def __init__(self, message: str, disturbances: tuple[MagDisturbance, ...] = ()):
        super().__init__(message)
        self.message, self.disturbances = message, disturbances


def _fit(x: np.ndarray, robust: bool, most: int = MAX_FIT_SAMPLES) -> EllipsoidFit:
    """The ellipsoid of (at most ``most`` of) the samples ``x``. Where there is none, or the
    field directions it gives reach less than MIN_COVERAGE of the sphere (an ellipsoid
    through a patch of it is not determined: it may be any size), the sphere (hard iron and
    field only, the soft iron held at the identity: what offsets-only tools fit) if it
    reaches MIN_SPHERE_COVERAGE; else MagUnfit."""
    if len(x) < 20:
        raise MagUnfit(f"{len(x)} undisturbed samples, an ellipsoid needs 20 or more")
    x = _subsample(x, most)
    try:
        fit = fit_ellipsoid(x, robust=robust)
    except (ValueError, np.linalg.LinAlgError) as e:
        raise MagUnfit(f"no ellipsoid fits the samples ({e})") from None
    if is_ellipsoid(fit.G) and _coverage(x, fit) >= MIN_COVERAGE:
        return fit
    try:
        sphere = sphere_fit(x)
    except (ValueError, np.linalg.LinAlgError):
        sphere = None
    covered = 0.0 if sphere is None else _coverage(x, sphere)
    if covered >= MIN_SPHERE_COVERAGE:
        return sphere
    raise MagUnfit(f"the undisturbed samples reach {covered:.0%} of the field's directions "
                   f"({MIN_SPHERE_COVERAGE:.0%} at the least for the hard iron alone, "
                   f"{MIN_COVERAGE:.0%} for the soft iron): turn the device through every "
                   "direction, upside down included")


def _coverage(x: np.ndarray, fit: EllipsoidFit) -> float:
    return sphere_coverage(_unit((x[::max(1, len(x) // 5000)] - fit.c) @ fit.G),
                           COVERAGE_ANGLE_DEG)[0]


def _still_steps(x: np.ndarray, t: np.ndarray, block_times: np.ndarray | None
                 ) -> list[tuple[float, float, float]]:
    """Steps of the field inside still blocks, where the sensor did not turn so the field
    cannot have changed: ``(t_step, t_block_end, size)`` with ``size`` the jump in the raw
    unit. The split of a block that best separates two levels (the largest
    ``|mean after - mean before| sqrt(k (n - k) / n)``) against the noise of the block's first
    differences: far beyond it (STEP_Z), and more than STEP_FLOOR of the field's scale (half
    the samples' range, 1st to 99th percentile, per axis, averaged: the field's norm for a
    full sphere, less for a part of it; a filtered signal's first differences understate its
    noise, and the floor keeps a small drift of the sensor's offset from counting)."""
    out: list[tuple[float, float, float]] = []
    if block_times is None or len(block_times) == 0:
        return out
    lo, hi = np.percentile(x, [1, 99], axis=0)
    scale = float(np.mean(hi - lo) / 2)
    for (a, b), (_t0, t1) in zip(samples_within(t, block_times), block_times):
        n = b - a
        if n < 4 * MIN_BLOCK_SAMPLES:
            continue
        y = x[a:b]
        noise = 1.4826 * np.median(np.abs(np.diff(y, axis=0)), axis=0) / np.sqrt(2)
        noise = np.maximum(noise, 1e-9 * scale)
        k = np.arange(1, n)
        cs = np.cumsum(y, axis=0)[:-1]
        before = cs / k[:, None]
        after = (cs[-1] + y[-1] - cs) / (n - k)[:, None]
        jump = after - before
        z = np.sqrt(np.sum((jump / noise) ** 2, axis=1) * k * (n - k) / n)
        i = int(np.argmax(z))
        size = float(np.linalg.norm(jump[i]))
        if z[i] > STEP_Z and size > STEP_FLOOR * scale:
            out.append((float(t[a + i + 1]), float(t1), size))
    return out


def _disturbed(x: np.ndarray, t: np.ndarray, prior: np.ndarray
               ) -> tuple[EllipsoidFit, np.ndarray, list[MagDisturbance]]:
    """The ellipsoid fit on the undisturbed samples, the mask of those samples and the
    windows left out: a robust fit (Cauchy loss) of the samples not left out by ``prior``
    (False: a step inside a still block), then a fixed point: judge every window by the fit,
    leave out those that depart, fit again (plain least squares), until the windows left out
    repeat."""
    win, _ = _window_index(t)
    nwin = int(win[-1]) + 1
    count = np.bincount(win, minlength=nwin)
    valid = count >= min(WINDOW_MIN_SAMPLES, max(len(t) // 50, 3))
    bad = np.zeros(nwin, bool)
    seen = {bad.tobytes()}
    fit = _fit(x[prior], robust=True, most=MAX_SEARCH_SAMPLES)
    for _ in range(8):
        r = fit.residuals(x)
        mean = np.bincount(win, r, minlength=nwin) / np.maximum(count, 1)
        ref = valid & ~bad
        if ref.sum() < 5:
            break
        centre = float(np.median(mean[ref]))
        spread = 1.4826 * float(np.median(np.abs(mean[ref] - centre)))
        far = valid & (np.abs(mean - centre) > max(DISTURB_K * spread, DISTURB_FLOOR))
        # a window next to a departing one holds the disturbance's onset or end
        grown = far | np.r_[far[1:], False] | np.r_[False, far[:-1]]
        if grown.sum() > 0.6 * valid.sum():
            break  # most of the recording departing is no disturbance but a bad fit
        bad, key = grown, grown.tobytes()
        if key in seen:  # the same windows again (or a cycle): the fixed point
            break
        seen.add(key)
        fit = _fit(x[~bad[win] & prior], robust=False, most=MAX_SEARCH_SAMPLES)
    keep = ~bad[win] & prior
    fit = _fit(x[keep], robust=False)
    r = fit.residuals(x)
    out = []
    for a, b in runs_of_true(bad):
        inside = (win >= a) & (win < b)
        dev = np.abs(r[inside] - np.median(r[keep])) * 100
        out.append(MagDisturbance(float(t[inside][0]), float(t[inside][-1]), "norm",
                                  float(np.median(dev)), float(np.max(dev)), "%"))
    return fit, keep, out


def _block_means(x: np.ndarray, t: np.ndarray, keep: np.ndarray, block_times: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Each still block's mean raw field (B, 3) over the magnetometer's samples inside its
    time interval, and whether it has enough samples, none of them disturbed."""
    rng = samples_within(t, block_times)
    n = rng[:, 1] - rng[:, 0]
    cs = np.vstack([np.zeros((1, 3)), np.cumsum(x, axis=0)])
    bad = np.r_[0, np.cumsum(~keep)]
    means = (cs[rng[:, 1]] - cs[rng[:, 0]]) / np.maximum(n, 1)[:, None]
    ok = (n >= MIN_BLOCK_SAMPLES) & (bad[rng[:, 1]] - bad[rng[:, 0]] == 0)
    return means, ok


def _block_residuals(p: np.ndarray, R0: np.ndarray, raw_means: np.ndarray, u: np.ndarray
                     ) -> np.ndarray:
    """``u_k . exp([d]x) R0 h_k + sin(dip)`` for ``p = (g6, b3, d3, dip)``."""
    G = sym_from_vec(p[:6])
    h = _unit((raw_means - p[6:9]) @ G)
    R = _rotation(p[9:12]) @ R0
    return np.einsum("ki,ij,kj->k", u, R, h) + np.sin(p[12])


def _sequential(fit: EllipsoidFit, R0: np.ndarray, dip0: float, raw_means: np.ndarray,
                u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """R_am and the dip fitted on the blocks with the ellipsoid held at the samples' fit;
    returns ``p`` (13, ``d = 0`` about the returned ``R``), ``R`` and the covariance of ``p``:
    the ellipsoid's own (the samples'), and for ``(d, dip)`` the blocks' spread plus the
    ellipsoid's errors carried through, ``A C A'`` with ``A = -(J2'J2)^-1 J2' J1`` (J1, J2
    the block residuals' derivatives by the ellipsoid's and by ``(d, dip)``'s parameters)."""
    g = fit.params
    R = R0

    def rb(q: np.ndarray, R: np.ndarray) -> np.ndarray:
        return _block_residuals(np.r_[g, q], R, raw_means, u)

    q = np.r_[np.zeros(3), dip0]
    for _ in range(2):  # the second pass starts at d = 0 about the first's rotation
        from scipy.optimize import least_squares  # imported where a fit runs (bench/startup.md)

        q = least_squares(rb, q, args=(R,), method="lm").x
        R = _rotation(q[:3]) @ R
        q[:3] = 0.0
    p = np.r_[g, q]
    # the parameters' natural scales, for the finite differences
    step = np.r_[np.full(6, 1e-6 * np.abs(fit.G).max()), np.full(3, 1e-6 / np.abs(fit.G).max()),
                 np.full(4, 1e-7)]
    J = np.empty((len(u), 13))
    for k in range(13):  # central differences of B block rows: no per-sample loop
        e = np.zeros(13)
        e[k] = step[k]
        J[:, k] = (_block_residuals(p + e, R, raw_means, u)
                   - _block_residuals(p - e, R, raw_means, u)) / (2 * step[k])
    r = _block_residuals(p, R, raw_means, u)
    s2 = float(r @ r) / max(len(u) - 4, 1)
    J1, J2 = J[:, :9], J[:, 9:]
    N2 = _inverse_normal(J2)
    A = -N2 @ J2.T @ J1
    C11 = fit.cov
    cov = np.zeros((13, 13))
    cov[:9, :9] = C11
    cov[9:, 9:] = s2 * N2 + A @ C11 @ A.T
    cov[9:, :9] = A @ C11
    cov[:9, 9:] = cov[9:, :9].T
    return p, R, cov


def _usable_turns(turns: Turns | None, ok: np.ndarray) -> Turns | None:
    """The turns between usable blocks, their blocks renumbered among those (None: fewer than
    MIN_TURNS)."""
    if turns is None or not len(turns.pairs):
        return None
    pairs = np.asarray(turns.pairs, np.int64)
    keep = ok[pairs[:, 0]] & ok[pairs[:, 1]]
    if keep.sum() < MIN_TURNS:
        return None
    index = np.cumsum(ok) - 1
    moved = turns.moved[:, keep] if len(turns.moved) else turns.moved
    return Turns(index[pairs[keep]], turns.q[keep], moved)


def _still_alignment(p: np.ndarray, R: np.ndarray, means: np.ndarray, u: np.ndarray
                     ) -> Alignment:
    r = _block_residuals(p, R, means, u)
    return Alignment("still blocks", len(u), 0, 0.0,
                     float(np.sqrt(r @ r / max(len(u) - 4, 1))), None, 0.0)


def _inverse_normal(J: np.ndarray) -> np.ndarray:
    """``(J'J)^-1`` with the columns scaled to unit norm first: in tesla the ellipsoid's
    entries are 1e4 and the centre's 1e-5, and ``J'J`` unscaled spans 1e18, where a
    pseudo-inverse truncates real directions."""
    d = 1.0 / np.maximum(np.linalg.norm(J, axis=0), 1e-300)
    Js = J * d
    return np.linalg.pinv(Js.T @ Js) * np.outer(d, d)


def _headings(p: np.ndarray, R0: np.ndarray, raw_means: np.ndarray, u: np.ndarray
              ) -> np.ndarray:
    """Each still pose's heading (rad) from the calibrated field in the accelerometer's
    frame: its horizontal part (normal to ``u``) against the horizontal part of the
    accelerometer's x axis (its y axis where x points nearly up)."""
    G = sym_from_vec(p[:6])
    R = _rotation(p[9:12]) @ R0
    m = ((raw_means - p[6:9]) @ G) @ R.T
    ref = np.where(np.abs(u[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    e1 = _unit(ref - np.sum(ref * u, axis=1, keepdims=True) * u)
    e2 = np.cross(u, e1)
    return np.arctan2(np.sum(m * e2, axis=1), np.sum(m * e1, axis=1))


def _heading_std_deg(p: np.ndarray, R: np.ndarray, cov: np.ndarray, raw_means: np.ndarray,
                     u: np.ndarray) -> float:
    """The heading's standard error at each still pose that the covariance of the 13
    parameters predicts (their derivatives by central differences), RMS over the poses."""
    J = np.empty((len(u), 13))
    scale = np.sqrt(np.maximum(np.diag(cov), 1e-30))
    for k in range(13):
        e = np.zeros(13)
        e[k] = 1e-3 * scale[k]
        d = _headings(p + e, R, raw_means, u) - _headings(p - e, R, raw_means, u)
        J[:, k] = np.angle(np.exp(1j * d)) / (2 * e[k])
    var = np.einsum("ij,jk,ik->i", J, cov, J)
    return float(np.degrees(np.sqrt(np.mean(var))))


def _derived(p9: np.ndarray) -> np.ndarray:
    """``(M's 6 entries, F, b)`` of ``(G's 6 entries, b)``: ``F = det(G)^(-1/3)``,
    ``M = F G``."""
    G = sym_from_vec(p9[:6])
    F = np.linalg.det(G) ** (-1.0 / 3.0)
    return np.r_[vec_from_sym(F * G), F, p9[6:9]]


def _derived_cov(p9: np.ndarray, cov9: np.ndarray) -> np.ndarray:
    """The delta method: ``J cov J'`` with the derivatives of :func:`_derived` by central
    differences."""
    J = np.empty((10, 9))
    for k in range(9):
        h = 1e-6 * max(abs(p9[k]), np.abs(p9[:6]).max() * 1e-3)
        e = np.zeros(9)
        e[k] = h
        J[:, k] = (_derived(p9 + e) - _derived(p9 - e)) / (2 * h)
    return J @ cov9 @ J.T


def _held_out_pct(x: np.ndarray, t: np.ndarray, whole: EllipsoidFit | None = None
                  ) -> float | None:
    """The norm residual RMS (%) of each half of the recording's time judged by the fit of
    the other half; None where a half reaches less than MIN_SPHERE_COVERAGE of the
    directions as the ``whole`` recording's fit sees them."""
    if len(x) < 40:
        return None
    cut = np.searchsorted(t, np.median(t))
    a, b = x[:cut], x[cut:]
    try:  # each half fitted as the whole is (M8r: its own L-curve)
        fb, fa = regularised_fit(_subsample(b)).fit, regularised_fit(_subsample(a)).fit
    except (ValueError, np.linalg.LinAlgError):
        return None
    if whole is not None and min(_coverage(a, whole), _coverage(b, whole)) < MIN_SPHERE_COVERAGE:
        # a half that reaches too few directions for even the hard iron (the whole would be
        # refused) judges nothing: its fit extrapolates, or escapes to a huge sphere whose
        # residual relative to the radius is near zero (x-io's second half: 1e-8 %)
        return None
    ra, rb = fb.residuals(a), fa.residuals(b)
    r = np.r_[ra, rb]
    return float(100 * np.sqrt(np.mean(r * r)))


def _missing_words(uncovered: np.ndarray, frame: str) -> str:
    """The missing field direction in plain words, and what to do."""
    v = uncovered.mean(axis=0)
    if np.linalg.norm(v) < 0.3:  # missing all round: name one of the missing directions
        v = uncovered[0]
    words = axis_words(v)
    return (f"the field never pointed along the {frame}'s {words}: turn the device so that "
            f"its {words} side faces magnetic north and down, along the field (turning it "
            "upside down about an axis that points north reaches the directions missing)")


def calibrate_magnetometer(stream: Stream, block_times: np.ndarray | None = None,
                           up: np.ndarray | None = None, turns: Turns | None = None,
                           up_moved: np.ndarray | None = None) -> MagFit:
    """Fit M8 to a magnetometer stream; ``block_times`` (B, 2) the still blocks' time
    intervals (the same clock as the stream's) and ``up`` (B, 3) the calibrated
    accelerometer's mean in each (any unit) for ``R_am`` and the dip; ``turns`` the calibrated
    gyroscope's rotations between those blocks (M8t), fitted with them where MIN_TURNS or more
    join usable blocks; ``up_moved`` (J, B, 3) ``up`` under the accelerometer's model moved
    by each of its error steps (their outer products sum to its covariance), carried through
    to R_am and the dip in that fit. Without blocks, or with fewer than MIN_BLOCKS usable blocks
    (MIN_BLOCKS_WITH_TURNS with turns), ``R_am`` and the dip are not estimated."""
    x = np.asarray(stream.values, float)
    t = np.asarray(stream.t, float)
    finite = np.isfinite(x).all(axis=1) & np.isfinite(t)
    x, t = x[finite], t[finite]
    if len(x) < 10 or not np.ptp(x, axis=0).all():
        # a sender that fills the fields with zeros (MAVLink without a compass), or a stream
        # cut to nothing: no field to fit
        raise MagUnfit(f"{len(x)} samples, and an axis that never changes: no magnetometer "
                       "readings to fit")
    steps = _still_steps(x, t, None if block_times is None else np.asarray(block_times, float))
    prior = np.ones(len(t), bool)
    disturbances = []
    for t0, t1, size in steps:
        prior &= ~((t >= t0) & (t <= t1))
        disturbances.append(MagDisturbance(t0, t1, "step", size, size,
                                           stream.unit or "raw units"))
    try:
        fit, keep, found = _disturbed(x, t, prior)
    except MagUnfit as e:
        raise MagUnfit(e.message, tuple(disturbances)) from None
    # a step at the edge of a part whose norm departs is that part's onset or end: said once
    width = _window_index(t)[1]
    disturbances = [d for d in disturbances if not any(
        f.t_start - width <= d.t_start <= f.t_end + width for f in found)] + found
    warnings: list[RunWarning] = []
    xk, tk = x[keep], t[keep]
    try:  # M8r: the fit returned, its shape held towards a sphere as the L-curve says
        reg = regularised_fit(_subsample(xk))
    except (ValueError, np.linalg.LinAlgError) as e:
        raise MagUnfit(f"no ellipsoid fits the samples ({e})", tuple(disturbances)) from None
    fit = reg.fit

    B = 0 if block_times is None else len(block_times)
    alignment = None
    block_dip = np.full(B, np.nan)
    block_used = np.zeros(B, bool)
    R = dip = heading = None
    std_R = std_dip = None
    if B:
        means, ok = _block_means(x, t, keep, np.asarray(block_times, float))
        u_all = _unit(np.asarray(up, float))
        for attempt in range(4):  # blocks whose dip departs are left out, the rest refitted
            used_turns = _usable_turns(turns, ok)
            need = MIN_BLOCKS if used_turns is None else MIN_BLOCKS_WITH_TURNS
            if ok.sum() < need:
                R = dip = None
                break
            h = _unit((means[ok] - fit.c) @ fit.G)
            try:
                if used_turns is None:
                    R0, s0 = closed_form(u_all[ok], h)
                    p, R, cov = _sequential(fit, R0, float(np.arcsin(s0)), means[ok],
                                            u_all[ok])
                    alignment = _still_alignment(p, R, means[ok], u_all[ok])
                else:
                    Qt = np.transpose(quat.to_matrix(used_turns.q), (0, 2, 1))
                    R0, s0 = closed_form(u_all[ok], h, used_turns.pairs[:, 0],
                                         used_turns.pairs[:, 1], Qt)
                    p, R, cov, alignment = fit_with_turns(fit.params, fit.cov, R0,
                                                          float(np.arcsin(s0)), means[ok],
                                                          u_all[ok], used_turns,
                                                          None if up_moved is None else
                                                          _unit(np.asarray(up_moved)[:, ok]))
            except (ValueError, np.linalg.LinAlgError) as e:  # blocks that determine nothing
                R = dip = None
                warnings.append(RunWarning("mag_no_alignment", "the rotation to the "
                                           f"accelerometer could not be fitted ({e})"))
                break
            dip = float(p[12])
            hh = _unit((means - fit.c) @ fit.G)
            block_dip = np.degrees(-np.arcsin(np.clip(np.einsum("ki,ij,kj->k", u_all, R, hh),
                                                      -1, 1)))
            block_dip[~np.isfinite(means).all(axis=1)] = np.nan
            med = float(np.median(block_dip[ok]))
            spread = 1.4826 * float(np.median(np.abs(block_dip[ok] - med)))
            off = ok & (np.abs(block_dip - med) > max(DIP_K * spread, DIP_FLOOR_DEG))
            if not off.any() or attempt == 3:
                break
            for k in np.flatnonzero(off):
                disturbances.append(MagDisturbance(float(block_times[k, 0]),
                                                   float(block_times[k, 1]), "dip",
                                                   float(abs(block_dip[k] - med)),
                                                   float(abs(block_dip[k] - med)), "deg"))
            ok = ok & ~off
        if R is not None:
            block_used = ok.copy()
            heading = _heading_std_deg(p, R, cov, means[ok], u_all[ok])
            std = np.sqrt(np.diag(cov))
            std_R, std_dip = np.degrees(std[9:12]), float(np.degrees(std[12]))
            cov_out = cov
        elif not any(w.code == "mag_no_alignment" for w in warnings):
            warnings.append(RunWarning(
                "mag_no_alignment", f"only {int(ok.sum())} still blocks hold undisturbed "
                f"magnetometer samples ({MIN_BLOCKS} needed, {MIN_BLOCKS_WITH_TURNS} with "
                f"{MIN_TURNS} turns of a calibrated gyroscope): the rotation to the "
                "accelerometer and the dip are not estimated"))
    if R is None:
        cov_out = fit.cov
    p9 = fit.params
    d = _derived(p9)
    F = float(d[6])
    M = sym_from_vec(d[:6])
    dstd, undetermined = _data_std(p9, reg, F)
    r_in = fit.residuals(xk)
    dip_spread = None
    if R is not None and block_used.sum() > 1:
        dip_spread = float(np.std(block_dip[block_used], ddof=1))
    cal = _unit((xk[::max(1, len(xk) // 50_000)] - fit.c) @ fit.G)
    frame = "magnetometer"
    if R is not None:
        cal, frame = cal @ R.T, "accelerometer"
    covered, uncovered = sphere_coverage(cal, COVERAGE_ANGLE_DEG)
    missing = None
    if covered < GOOD_COVERAGE and len(uncovered):
        missing = _missing_words(uncovered, frame)
        warnings.append(RunWarning("mag_coverage", f"the field reached {covered:.0%} of "
                                   f"directions: {missing}"))
    quality = MagQuality(norm_rms_pct=float(100 * np.sqrt(np.mean(r_in * r_in))),
                         norm_rms_held_out_pct=_held_out_pct(xk, tk, fit),
                         dip_spread_deg=dip_spread, coverage=covered, missing=missing,
                         blocks=int(block_used.sum()), heading_std_deg=heading)
    soft_iron = not any(n.startswith("M") for n in undetermined)
    if undetermined:
        warnings.append(RunWarning(
            "mag_soft_iron_not_estimated" if not soft_iron else "mag_undetermined",
            f"the field reached {covered:.0%} of directions, too few to determine "
            f"{', '.join(undetermined)} (each left more than {UNDETERMINED_STD:g} of the "
            "field uncertain by the data alone): the soft iron is held near a sphere by "
            f"the prior (lambda {reg.lam:.2g}, the L-curve's corner) and those are given no "
            "standard error; turn the device through more directions for the soft iron"))
    if disturbances:
        left = int((~keep).sum())
        warnings.insert(0, RunWarning(
            "mag_disturbed", f"the magnetic field was not constant in "
            f"{len(disturbances)} part(s) of the recording: "
            f"{'; '.join(dd.text() for dd in disturbances)}; left out of the magnetometer's "
            f"calibration ({left} samples, {left / len(x):.0%})"))
    std_M = sym_from_vec(dstd[:6])
    return MagFit(M=M, b=p9[6:9].copy(), field=F, R_am=R,
                  dip_deg=None if dip is None else float(np.degrees(dip)),
                  std_M=std_M, std_b=dstd[7:10], std_field=float(dstd[6]),
                  std_R_am_deg=std_R, std_dip_deg=std_dip, cov=cov_out, unit=stream.unit,
                  stream=stream.name, samples=len(stream.t), used=_full_mask(finite, keep),
                  start=fit.start, disturbances=tuple(disturbances), quality=quality,
                  block_dip_deg=block_dip, block_used=block_used, warnings=tuple(warnings),
                  soft_iron=soft_iron, alignment=None if R is None else alignment,
                  se_design_effect=fit.deff,
                  se_block_s=float(fit.block * (tk[-1] - tk[0]) / max(fit.n - 1, 1)),
                  block_times=None if block_times is None
                  else np.array(block_times, float).reshape(-1, 2),
                  lcurve=_lcurve(reg), lam=reg.lam, undetermined=undetermined)


# the names of _derived's entries, for the parameters the data leave open
_DERIVED_NAMES = ("M_xx", "M_xy", "M_xz", "M_yy", "M_yz", "M_zz", "field", "b_x", "b_y", "b_z")


def _data_std(p9: np.ndarray, reg: RegularisedFit, F: float
              ) -> tuple[np.ndarray, tuple[str, ...]]:
    """The standard errors of ``(M's 6 entries, F, b)`` from the data alone (M8r: the prior
    is no measurement), NaN past UNDETERMINED_STD (of the field for F and b), and the names
    of those; the soft iron's all where lambda is the largest (M8r: held at the sphere)."""
    std = np.sqrt(np.clip(np.diag(_derived_cov(p9, reg.cov_data)), 0, None))
    limit = np.r_[np.full(6, UNDETERMINED_STD), np.full(4, UNDETERMINED_STD * abs(F))]
    over = ~(std <= limit)
    if reg.corner == len(reg.lambdas) - 1:
        # the sphere's end: the curve said the shape is not determined (no corner, and cut,
        # straight or not determined at its plain end), whatever the errors linearised at the
        # sphere say (a cap's: 0.005, where the plain fit's M was 0.042 off)
        over[:6] = True
    return (np.where(over, np.nan, std),
            tuple(n for n, o in zip(_DERIVED_NAMES, over) if o))


def _lcurve(reg: RegularisedFit) -> LCurve:
    """M8r's curve as the accelerometer's (thetas in the raw unit, G and b)."""
    return LCurve(lambdas=reg.lambdas, residual_norm=reg.rho, solution_norm=reg.eta,
                  thetas=reg.params, corner=reg.corner, curvature=reg.curvature)


def _full_mask(finite: np.ndarray, keep: np.ndarray) -> np.ndarray:
    out = np.zeros(len(finite), bool)
    out[np.flatnonzero(finite)[keep]] = True
    return out
