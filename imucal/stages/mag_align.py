"""The magnetometer's rotation to the accelerometer from the still blocks and the gyroscope's
turns together (M8 and M8t, docs/method.md §9).

In still block ``k`` the calibrated up ``u_k`` and the corrected field direction ``h_k`` keep
the world's angle (M8: ``u_k . R_am h_k = -sin(dip)``); over the turn from block ``a`` to
block ``b`` the calibrated gyroscope's integrated rotation ``R_ab`` (M4, M5) carries the field
as it carries gravity (M8t: ``R_am h_b = R_ab^T R_am h_a``). Both go into one weighted least
squares fit of ``R_am`` and the dip, the ellipsoid held at the samples' fit; each group is
weighted by its own residual scatter, with the degrees of freedom the fit takes from it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from imucal.numerics import quaternion as quat
from imucal.numerics.ellipsoid import sym_from_vec

# Below this many usable turns the still blocks alone decide (M8t needs three turns about
# different axes to hold a rotation by itself).
MIN_TURNS = 3
# With the turns, still blocks needed (the dip is in M8 only).
MIN_BLOCKS_WITH_TURNS = 3
# The turns' share of the rotation's information above which R_am is said to come from the
# turns (below 1 - this: from the still blocks), else from both.
SHARE_SAID = 0.9
# A turn whose residual exceeds TURN_K times the turns' robust scatter (the median residual
# over the median of a Rayleigh variable: 2e-5 of honest turns go beyond 5) and TURN_FLOOR_DEG
# is left out: the field turned by other than the gyroscope measured between the blocks, a
# turn about the vertical inside what the accelerometer took for a still block (gravity
# cannot see it, the field can).
TURN_K = 5.0
TURN_FLOOR_DEG = 0.05


@dataclass(frozen=True)
class Turns:
    """The calibrated gyroscope's turns between still blocks: ``pairs`` (K, 2) the blocks
    before and after each (indices into the still blocks given beside), ``q`` (K, 4) the
    body's rotation over it (M5: ``u_b = R(q)^T u_a``), and ``moved`` (J, K, 4) the same
    turns integrated again with each of the gyroscope's parameters moved by its standard
    error (its errors carried through; empty: not carried)."""

    pairs: np.ndarray
    q: np.ndarray
    moved: np.ndarray


@dataclass(frozen=True)
class Alignment:
    """What determined ``R_am``: ``evidence`` "still blocks", "turns" or "still blocks and
    turns"; the blocks and turns used, the turns' share of the rotation's information (the
    trace of their part of the weighted normal matrix), each group's residual scatter (the
    still rows' in units of ``sin``, the turns' in degrees) and the gyroscope's share of the
    rotation's variance; ``turns_left_out``: turns whose field departed from the gyroscope's
    rotation (TURN_K)."""

    evidence: str
    blocks: int
    turns: int
    turns_share: float
    sigma_still: float | None
    sigma_turn_deg: float | None
    gyro_share: float
    turns_left_out: int = 0

    def to_dict(self) -> dict:
        return {"evidence": self.evidence, "still_blocks": self.blocks, "turns": self.turns,
                "turns_left_out": self.turns_left_out, "turns_share": self.turns_share,
                "sigma_still": self.sigma_still, "sigma_turn_deg": self.sigma_turn_deg,
                "gyro_share": self.gyro_share}


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def rotation(v: np.ndarray) -> np.ndarray:
    """The rotation matrix of a rotation vector (scipy's Rotation would cost every run the
    import of scipy.spatial)."""
    return quat.to_matrix(quat.from_rotvec(np.asarray(v, float)))


def closed_form(u: np.ndarray, h: np.ndarray, a: np.ndarray | None = None,
                b: np.ndarray | None = None, Qt: np.ndarray | None = None
                ) -> tuple[np.ndarray, float]:
    """``R`` and ``sin(dip)`` from M8's still rows ``(u_k kron h_k) . vec(R) + s = 0`` and,
    given turns (``a``, ``b``, ``Qt``), M8t's turn rows ``(I kron h_b' - Qt kron h_a') vec(R)
    = 0`` together (linear in the nine entries of ``R`` and ``s``: their null vector, up to
    scale and sign), projected on the rotations. Axes of opposite handedness cannot be told
    from the still rows alone: a mirror ``R'`` fits as the rotation ``-R'`` with the dip's
    sign turned."""
    D = np.column_stack([(u[:, :, None] * h[:, None, :]).reshape(len(u), 9),
                         np.ones(len(u))])
    if a is not None and len(a):
        eye = np.eye(3)
        turn = (np.einsum("il,kj->kilj", eye, h[b]) - np.einsum("kil,kj->kilj", Qt, h[a]))
        turn = np.concatenate([turn.reshape(len(a) * 3, 9), np.zeros((len(a) * 3, 1))],
                              axis=1)
        D = np.vstack([D, turn])
    A = np.linalg.svd(D, full_matrices=False)[2][-1][:9].reshape(3, 3)
    if np.linalg.det(A) < 0:
        A = -A
    U, _, Vt = np.linalg.svd(A)
    R = U @ Vt
    s = -float(np.mean(np.einsum("ki,ij,kj->k", u, R, h)))
    return R, float(np.clip(s, -1.0, 1.0))


def _across(v: np.ndarray) -> np.ndarray:
    """(K, 2, 3): two unit vectors normal to each row of ``v`` and to each other."""
    ref = np.where(np.abs(v[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    e1 = unit(np.cross(v, ref))
    return np.stack([e1, np.cross(v, e1)], axis=1)


class _Problem:
    """The weighted residuals of M8 (still) and M8t (turns) in ``p = (g6, b3, d3, dip)``,
    ``R = exp([d]x) R0``; the turns' residuals projected across the predicted direction by
    ``E`` (fixed for a pass)."""

    def __init__(self, means: np.ndarray, u: np.ndarray, a: np.ndarray, b: np.ndarray):
        self.means, self.u, self.a, self.b = means, u, a, b
        self.w = np.ones(2)

    def parts(self, p: np.ndarray, R0: np.ndarray, Qt: np.ndarray, E: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
        G = sym_from_vec(p[:6])
        m = unit((self.means - p[6:9]) @ G) @ (rotation(p[9:12]) @ R0).T  # R h, each block
        still = np.einsum("ki,ki->k", self.u, m) + np.sin(p[12])
        pred = np.einsum("kij,kj->ki", Qt, m[self.a])
        turn = np.einsum("kci,ki->kc", E, m[self.b] - pred).ravel()
        return still, turn

    def residuals(self, p, R0, Qt, E) -> np.ndarray:
        still, turn = self.parts(p, R0, Qt, E)
        return np.r_[self.w[0] * still, self.w[1] * turn]

    def predicted(self, p, R0, Qt) -> np.ndarray:
        G = sym_from_vec(p[:6])
        m = unit((self.means[self.a] - p[6:9]) @ G) @ (rotation(p[9:12]) @ R0).T
        return np.einsum("kij,kj->ki", Qt, m)


def _jacobian(f, p: np.ndarray, step: np.ndarray) -> np.ndarray:
    cols = []
    for k in range(len(p)):  # central differences over 13 parameters: rows are blocks, turns
        e = np.zeros(len(p))
        e[k] = step[k]
        cols.append((f(p + e) - f(p - e)) / (2 * step[k]))
    return np.column_stack(cols)


def _inverse_normal(J: np.ndarray) -> np.ndarray:
    """``(J'J)^-1`` with the columns scaled to unit norm first (tesla's entries span 1e18)."""
    d = 1.0 / np.maximum(np.linalg.norm(J, axis=0), 1e-300)
    Js = J * d
    return np.linalg.pinv(Js.T @ Js) * np.outer(d, d)


def fit_with_turns(g9: np.ndarray, cov9: np.ndarray, R0: np.ndarray, dip0: float,
                   means: np.ndarray, u: np.ndarray, turns: Turns,
                   u_moved: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, Alignment]:
    """:func:`_fit_turns`, then again without the turns that depart (TURN_K), until none
    does or MIN_TURNS would be left."""
    left = 0
    while True:
        p, R, cov, align, resid = _fit_turns(g9, cov9, R0, dip0, means, u, turns, u_moved)
        scale = float(np.median(resid)) / np.sqrt(2 * np.log(2))
        off = resid > max(TURN_K * scale, np.radians(TURN_FLOOR_DEG))
        if not off.any() or (~off).sum() < MIN_TURNS:
            return p, R, cov, replace(align, turns_left_out=left)
        left += int(off.sum())
        moved = turns.moved[:, ~off] if len(turns.moved) else turns.moved
        turns = Turns(turns.pairs[~off], turns.q[~off], moved)
        R0, dip0 = R, float(p[12])


def _fit_turns(g9: np.ndarray, cov9: np.ndarray, R0: np.ndarray, dip0: float,
               means: np.ndarray, u: np.ndarray, turns: Turns, u_moved: np.ndarray | None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, Alignment, np.ndarray]:
    """R_am and the dip from M8 and M8t in one weighted fit, the ellipsoid ``g9`` (its
    covariance ``cov9``) held. ``means`` (B, 3) the raw field in the still blocks used, ``u``
    (B, 3) their unit up, ``turns.pairs`` indices into them. Returns ``p`` (13, ``d = 0`` about
    the returned ``R``), ``R``, the covariance of ``p``, what determined ``R`` and each turn's
    residual (rad, across the predicted direction). The covariance: the
    weighted normal matrix's inverse, the ellipsoid's errors carried through
    (``A C A'``, ``A = -(J2'WJ2)^-1 J2'W J1``), the gyroscope's (each moved turn set's
    shift of the solution, one Gauss-Newton step) and the accelerometer's (each of
    ``u_moved`` (J, B, 3), the unit up under a moved M2, likewise)."""
    from scipy.optimize import least_squares  # imported where a fit runs (bench/startup.md)

    a, b = turns.pairs[:, 0], turns.pairs[:, 1]
    Qt = np.transpose(quat.to_matrix(turns.q), (0, 2, 1))
    prob = _Problem(means, u, a, b)
    R = R0
    q = np.r_[np.zeros(3), dip0]
    nb, nt = len(u), 2 * len(a)
    step = np.r_[np.full(6, 1e-6 * np.abs(sym_from_vec(g9[:6])).max()),
                 np.full(3, 1e-6 / np.abs(sym_from_vec(g9[:6])).max()), np.full(4, 1e-7)]
    for _ in range(4):  # weights from each group's scatter, until they settle
        for _ in range(2):  # the second pass starts at d = 0 about the first's rotation
            E = _across(prob.predicted(np.r_[g9, q], R, Qt))
            q = least_squares(lambda x, R=R, E=E: prob.residuals(np.r_[g9, x], R, Qt, E), q,
                              method="lm").x
            R = rotation(q[:3]) @ R
            q[:3] = 0.0
        p = np.r_[g9, q]
        E = _across(prob.predicted(p, R, Qt))
        J2 = _jacobian(lambda x, R=R, E=E: prob.residuals(np.r_[g9, x], R, Qt, E), q,
                       step[9:])
        hat = np.einsum("ij,jk,ik->i", J2, _inverse_normal(J2), J2)
        still, turn = prob.parts(p, R, Qt, E)
        dof_s = max(nb - hat[:nb].sum(), 1.0)
        dof_t = max(nt - hat[nb:].sum(), 1.0)
        s_s = max(float(np.sqrt(still @ still / dof_s)), 1e-12)
        s_t = max(float(np.sqrt(turn @ turn / dof_t)), 1e-12)
        new = np.array([1.0 / s_s, 1.0 / s_t])
        settled = np.allclose(new, prob.w, rtol=1e-3)
        prob.w = new
        if settled:
            break

    def f(x: np.ndarray) -> np.ndarray:
        return prob.residuals(x, R, Qt, E)

    J = _jacobian(f, p, step)
    J1, J2 = J[:, :9], J[:, 9:]
    N2 = _inverse_normal(J2)
    A = -N2 @ J2.T @ J1
    gyro = np.zeros((4, 4))
    r0 = f(p)
    for moved in turns.moved:  # the gyroscope's errors: the solution's shift per parameter
        Qm = np.transpose(quat.to_matrix(moved), (0, 2, 1))
        shift = -N2 @ J2.T @ (prob.residuals(p, R, Qm, E) - r0)
        gyro += np.outer(shift, shift)
    acc = np.zeros((4, 4))
    for um in () if u_moved is None else u_moved:
        moved_prob = _Problem(means, um, a, b)
        moved_prob.w = prob.w
        shift = -N2 @ J2.T @ (moved_prob.residuals(p, R, Qt, E) - r0)
        acc += np.outer(shift, shift)
    cov = np.zeros((13, 13))
    cov[:9, :9] = cov9
    cov[9:, 9:] = N2 + A @ cov9 @ A.T + gyro + acc
    cov[9:, :9] = A @ cov9
    cov[:9, 9:] = cov[9:, :9].T
    info_s = np.trace(J2[:nb, :3].T @ J2[:nb, :3])
    info_t = np.trace(J2[nb:, :3].T @ J2[nb:, :3])
    share = float(info_t / (info_s + info_t))
    evidence = ("turns" if share > SHARE_SAID else "still blocks" if share < 1 - SHARE_SAID
                else "still blocks and turns")
    gyro_share = float(np.trace(gyro[:3, :3]) / max(np.trace(cov[9:12, 9:12]), 1e-300))
    resid = np.linalg.norm(turn.reshape(-1, 2), axis=1)
    return p, R, cov, Alignment(evidence, nb, len(a), share, s_s, float(np.degrees(s_t)),
                                gyro_share), resid
