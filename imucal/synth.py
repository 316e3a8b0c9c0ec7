"""Synthetic sessions with known ground truth (method.md §6 and the tests).

The device rests in random orientations and turns between them about a fixed body axis with a
minimum-jerk profile, so the true orientation and body rate are known in closed form at any
time: ``q(t) = q_(k-1) (x) exp(n theta s(tau) / 2)``, ``w(t) = n theta s'(tau)``. The ideal
accelerometer reads gravity in the body frame, ``R(q)^T e_z`` (rotation about the sensor's
centre, no linear acceleration). The raw signals are the inverse of the models M2 and M4 plus
white noise.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from imucal.models import SensorModel, acc_T, gyro_T
from imucal.numerics import quaternion as quat
from imucal.session import STANDARD_GRAVITY, Session
from imucal.streams import Stream


@dataclass(frozen=True)
class MagTruth:
    """The magnetometer that made a synthetic session (model M8 of :mod:`imucal.stages.mag`):
    ``m = R_am M (m_raw - b)`` with ``det M = 1``, ``|m| = field`` (raw unit) and the field
    ``dip_deg`` below the horizon. ``disturbance``: ``[t0, t1)`` in which a magnet carried
    with the sensor adds ``disturbance_field`` (raw unit, the magnetometer's frame) to the
    reading; None: an undisturbed field throughout."""

    M: np.ndarray
    b: np.ndarray
    R_am: np.ndarray
    field: float
    dip_deg: float
    unit: str = "gauss"
    rate: float = 50.0
    noise: float = 0.0
    disturbance: tuple[float, float] | None = None
    disturbance_field: np.ndarray | None = None

    def to_dict(self) -> dict:
        return {"M": self.M.tolist(), "b": self.b.tolist(), "R_am": self.R_am.tolist(),
                "field": self.field, "dip_deg": self.dip_deg, "unit": self.unit,
                "rate": self.rate, "noise": self.noise,
                "disturbance": None if self.disturbance is None else list(self.disturbance),
                "disturbance_field": None if self.disturbance_field is None
                else self.disturbance_field.tolist(),
                "model": "m = R_am M (m_raw - b), det M = 1, |m| = field "
                         "(imucal.stages.mag, M8)"}


@dataclass(frozen=True)
class Truth:
    """The models that made a synthetic session, in the raw signal's units.

    ``acc``/``gyro`` hold before ``t_change`` (or throughout), ``acc2``/``gyro2`` after it.
    ``gyro.b`` is the gyroscope bias at t = 0; it grows by ``gyro_drift`` rad/s per second.
    """

    acc: SensorModel
    gyro: SensorModel
    acc2: SensorModel | None = None
    gyro2: SensorModel | None = None
    t_change: float | None = None
    gyro_drift: np.ndarray = field(default_factory=lambda: np.zeros(3))
    g: float = 1.0
    pose_times: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    mag: MagTruth | None = None  # the magnetometer, when the session has one

    def to_dict(self) -> dict:
        def m(model: SensorModel | None) -> dict | None:
            if model is None:
                return None
            return {"T": model.T.tolist(), "K": model.K.tolist(), "b": model.b.tolist()}

        return {"accelerometer": m(self.acc), "gyroscope": m(self.gyro),
                "accelerometer_after_change": m(self.acc2), "gyroscope_after_change": m(self.gyro2),
                "t_change": self.t_change, "gyro_drift": self.gyro_drift.tolist(), "g": self.g,
                "still_intervals": self.pose_times.tolist(),
                "model": "a = T K (a_raw - b); w = T_g K_g (w_raw - b_g) (method.md M2, M4)"} | (
                    {} if self.mag is None else {"magnetometer": self.mag.to_dict()})


def random_acc_model(rng: np.random.Generator, mis: float = 0.01, scale: float = 0.03,
                     bias: float = 0.05) -> SensorModel:
    th = rng.normal(0.0, mis, 3)
    return SensorModel(T=acc_T(np.r_[th, 1, 1, 1, 0, 0, 0]), K=1.0 + rng.normal(0, scale, 3),
                       b=rng.normal(0.0, bias, 3))


def random_gyro_model(rng: np.random.Generator, mis: float = 0.01, scale: float = 0.03,
                      bias: float = 0.02) -> SensorModel:
    th = np.r_[rng.normal(0.0, mis, 6), 1, 1, 1]
    return SensorModel(T=gyro_T(th), K=1.0 + rng.normal(0, scale, 3), b=rng.normal(0, bias, 3))


def min_jerk(tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position s and rate ds/dtau of the minimum-jerk profile on tau in [0, 1]."""
    return (tau**3 * (10 - 15 * tau + 6 * tau**2), 30 * tau**2 * (1 - tau) ** 2)


@dataclass(frozen=True)
class Motion:
    """The scripted motion: a still interval per pose, a turn between consecutive poses."""

    q: np.ndarray  # (P, 4) pose orientations, body to world
    still: np.ndarray  # (P, 2) [t_start, t_end) of each still interval
    axis: np.ndarray  # (P-1, 3) body-frame unit axis of each turn
    angle: np.ndarray  # (P-1,) turn angle, rad

    def at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Orientation (N, 4) and body rate (N, 3) at times t, vectorised."""
        k = np.clip(np.searchsorted(self.still[:, 0], t, side="right") - 1, 0, len(self.q) - 1)
        q = self.q[k].copy()
        w = np.zeros((len(t), 3))
        moving = (t >= self.still[k, 1]) & (k < len(self.q) - 1)
        km = k[moving]
        t0, t1 = self.still[km, 1], self.still[km + 1, 0]
        tau = (t[moving] - t0) / (t1 - t0)
        s, ds = min_jerk(tau)
        rot = self.axis[km] * (self.angle[km] * s)[:, None]
        q[moving] = quat.multiply(self.q[km], quat.from_rotvec(rot))
        w[moving] = self.axis[km] * (self.angle[km] * ds / (t1 - t0))[:, None]
        return q, w


def make_motion(rng: np.random.Generator, poses: int, still: float, move: float,
                init_still: float, coplanar: bool = False) -> Motion:
    if coplanar:
        # Every turn about the body's x axis, by 30-120 deg either way: gravity (body frame)
        # stays in the y-z plane, a session that leaves directions unmeasured (issue 27).
        step = rng.uniform(np.radians(30), np.radians(120), poses) * rng.choice([-1, 1], poses)
        roll = np.cumsum(step) - step[0]
        q = quat.from_rotvec(np.outer(roll, [1.0, 0.0, 0.0]))
    else:
        q = quat.random_unit(poses, rng)
    rel = quat.multiply(quat.conjugate(q[:-1]), q[1:])  # q_k = q_(k-1) (x) rel: body-frame turn
    rv = quat.to_rotvec(rel)
    angle = np.linalg.norm(rv, axis=1)
    axis = rv / np.maximum(angle, 1e-12)[:, None]
    # Randomise durations a little, as a person would hold and turn.
    holds = still * rng.uniform(0.8, 1.2, poses)
    holds[0] = init_still
    moves = move * rng.uniform(0.8, 1.2, poses - 1)
    starts = np.concatenate([[0.0], np.cumsum(holds[:-1] + moves)])
    return Motion(q=q, still=np.column_stack([starts, starts + holds]), axis=axis, angle=angle)


def make_session(
    poses: int = 30,
    seed: int = 0,
    still: float = 3.0,
    move: float = 2.0,
    init_still: float = 5.0,
    acc_rate: float = 100.0,
    gyro_rate: float | None = None,
    acc_noise: float = 0.003,
    gyro_noise: float = 0.003,
    acc_truth: SensorModel | None = None,
    gyro_truth: SensorModel | None = None,
    gyro_drift: float = 0.0,
    change_at: float | None = None,
    acc_change: tuple[float, float] | None = None,
    acc_unit: str = "g",
    counts_per_g: float = 4096.0,
    gyro_unit: str = "rad/s",
    counts_per_rad_s: float = 939.65,
    mag_rate: float | None = None,
    mag_field: float = 0.5,
    mag_dip_deg: float = 65.0,
    mag_noise: float = 0.002,
    mag_hard: np.ndarray | None = None,
    mag_soft: np.ndarray | None = None,
    mag_R: np.ndarray | None = None,
    mag_disturbance: tuple[float, float] | None = None,
    mag_disturbance_size: float = 0.3,
    coplanar: bool = False,
    acc_drift: float = 0.0,
) -> tuple[Session, Truth]:
    """A session of ``poses`` still poses with turns between them, and the truth that made it.

    Noise is white, per axis, in g (accelerometer) and rad/s (gyroscope). ``change_at`` (a
    fraction of the poses) switches both sensors to freshly drawn parameters at the start of
    the turn that leaves that pose: a change of error conditions mid-session (method.md §2).
    ``acc_change`` (scale, bias) makes the accelerometer's change a knock of chosen size
    instead: each scale multiplied by 1 +- scale (random signs), the bias moved by ``bias`` g
    in a random direction (drawn apart, so the rest of the session is the same for any size).
    ``gyro_drift`` is the total change of the gyroscope bias over the session, rad/s.
    ``acc_unit`` "g", "m/s^2" or "counts"; ``gyro_unit`` "rad/s", "deg/s" or "counts". A
    session holds rad/s or counts (:class:`~imucal.session.Session`), so "deg/s" gives rad/s
    here: write it with ``write_session_mat(..., gyro_unit="deg/s")`` for a file in deg/s.

    ``mag_rate`` (Hz) adds a magnetometer in gauss on its own clock, as the session's first
    other stream (:func:`add_magnetometer`); the rest of the session is the same as without it.
    ``acc_drift`` is the total change of the accelerometer bias over the session, g, linear
    in time along a random direction (drawn apart: the rest of the session is the same).
    ``coplanar`` turns the device about its x axis only: every pose's gravity lies in one
    plane, so the data cannot determine every parameter (an ill-posed session).
    """
    rng = np.random.default_rng(seed)
    motion = make_motion(rng, poses, still, move, init_still, coplanar)
    duration = float(motion.still[-1, 1])
    gyro_rate = gyro_rate or acc_rate
    t_a = np.arange(int(duration * acc_rate)) / acc_rate
    t_g = np.arange(int(duration * gyro_rate)) / gyro_rate

    acc_truth = acc_truth or random_acc_model(rng)
    gyro_truth = gyro_truth or random_gyro_model(rng)
    acc2 = gyro2 = None
    t_change = None
    if change_at is not None:
        acc2, gyro2 = random_acc_model(rng, bias=0.08), random_gyro_model(rng)
        if acc_change is not None:
            knock = np.random.default_rng([seed, 1])
            direction = knock.normal(0, 1, 3)
            direction /= np.linalg.norm(direction)
            acc2 = SensorModel(T=acc_truth.T,
                               K=acc_truth.K * (1 + acc_change[0] * knock.choice([-1, 1], 3)),
                               b=acc_truth.b + acc_change[1] * direction)
        t_change = float(motion.still[int(change_at * poses), 1])
    drift = rng.normal(0, 1, 3)
    drift = gyro_drift * drift / np.linalg.norm(drift) / max(duration, 1e-9)

    q_a, _ = motion.at(t_a)
    ideal_a = quat.rotate_inverse(q_a, np.array([0.0, 0.0, 1.0]))
    _, w = motion.at(t_g)

    raw_a = _distort(ideal_a, t_a, acc_truth, acc2, t_change)
    raw_a += rng.normal(0, acc_noise, raw_a.shape)
    if acc_drift:
        way = np.random.default_rng([seed, 2]).normal(0, 1, 3)
        raw_a += np.outer(t_a / max(duration, 1e-9), acc_drift * way / np.linalg.norm(way))
    raw_g = _distort(w, t_g, gyro_truth, gyro2, t_change) + drift * t_g[:, None]
    raw_g += rng.normal(0, gyro_noise, raw_g.shape)

    g = 1.0
    if acc_unit == "m/s^2":
        g = STANDARD_GRAVITY
        raw_a *= g
        acc_truth, acc2 = _rescale(acc_truth, g, 0.0, g), _rescale(acc2, g, 0.0, g)
    elif acc_unit == "counts":
        raw_a = np.round(raw_a * counts_per_g + 32768.0)
        acc_truth = _rescale(acc_truth, counts_per_g, 32768.0, 1.0)
        acc2 = _rescale(acc2, counts_per_g, 32768.0, 1.0)
    if gyro_unit == "counts":
        raw_g = np.round(raw_g * counts_per_rad_s + 32768.0)
        gyro_truth = _rescale(gyro_truth, counts_per_rad_s, 32768.0, 1.0)
        gyro2 = _rescale(gyro2, counts_per_rad_s, 32768.0, 1.0)
        drift = drift * counts_per_rad_s

    session = Session(acc=raw_a, t_acc=t_a, gyro=raw_g, t_gyro=t_g, acc_unit=acc_unit,
                      gyro_unit="counts" if gyro_unit == "counts" else "rad/s",
                      source=f"synthetic(seed={seed}, poses={poses})")
    truth = Truth(acc=acc_truth, gyro=gyro_truth, acc2=acc2, gyro2=gyro2, t_change=t_change,
                  gyro_drift=drift, g=g, pose_times=motion.still)
    if mag_rate is not None:
        session, truth = add_magnetometer(
            session, truth, motion, seed, rate=mag_rate, field=mag_field, dip_deg=mag_dip_deg,
            noise=mag_noise, hard=mag_hard, soft=mag_soft, R_am=mag_R,
            disturbance=mag_disturbance, disturbance_size=mag_disturbance_size)
    return session, truth


def random_soft_iron(rng: np.random.Generator, scale: float = 0.05, cross: float = 0.02
                     ) -> np.ndarray:
    """A symmetric soft-iron matrix near the identity, normalised to ``det M = 1``."""
    off = rng.normal(0, cross, 3)
    M = np.diag(1.0 + rng.normal(0, scale, 3))
    M[0, 1] = M[1, 0] = off[0]
    M[0, 2] = M[2, 0] = off[1]
    M[1, 2] = M[2, 1] = off[2]
    return M / np.linalg.det(M) ** (1 / 3)


def add_magnetometer(session: Session, truth: Truth, motion: Motion, seed: int, rate: float,
                     field: float = 0.5, dip_deg: float = 65.0, noise: float = 0.002,
                     hard: np.ndarray | None = None, soft: np.ndarray | None = None,
                     R_am: np.ndarray | None = None,
                     disturbance: tuple[float, float] | None = None,
                     disturbance_size: float = 0.3) -> tuple[Session, Truth]:
    """The session with a magnetometer (gauss) in the world field ``field (cos dip, 0, -sin
    dip)`` (world z up, x magnetic north), read in the body frame, ``m_body =
    R(q)' f``, and made raw by the inverse of M8: ``m_raw = M^-1 R_am' m_body + b`` plus white
    noise ``noise`` per axis. Its own generator (``[seed, 23]``), so the accelerometer and
    gyroscope are those of the session without it. Unset parameters are drawn: hard iron
    about 0.2 field, soft iron 5 % scale and 2 % cross terms (det 1), ``R_am`` 2 degrees per
    axis."""
    rng = np.random.default_rng([seed, 23])
    hard = rng.normal(0, 0.2 * field, 3) if hard is None else np.asarray(hard, float)
    soft = random_soft_iron(rng) if soft is None else np.asarray(soft, float)
    if R_am is None:
        R_am = quat.to_matrix(quat.from_rotvec(rng.normal(0, np.radians(2.0), (1, 3))))[0]
    direction = rng.normal(0, 1, 3)
    duration = float(motion.still[-1, 1])
    t = np.arange(int(duration * rate)) / rate
    q, _ = motion.at(t)
    dip = np.radians(dip_deg)
    world = field * np.array([np.cos(dip), 0.0, -np.sin(dip)])
    body = quat.rotate_inverse(q, world)
    raw = np.linalg.solve(soft, (body @ R_am).T).T + hard  # M^-1 R_am' m_body + b
    extra = None
    if disturbance is not None:
        extra = disturbance_size * field * direction / np.linalg.norm(direction)
        inside = (t >= disturbance[0]) & (t < disturbance[1])
        raw[inside] += np.linalg.solve(soft, extra)  # reads as extra after M: a magnet
    raw += rng.normal(0, noise, raw.shape)
    stream = Stream("mag", "mag", t, raw, "gauss", "synthetic magnetometer",
                    time_source="the synthetic clock")
    mt = MagTruth(M=soft, b=hard, R_am=R_am, field=float(field), dip_deg=float(dip_deg),
                  rate=float(rate), noise=float(noise),
                  disturbance=None if disturbance is None else tuple(map(float, disturbance)),
                  disturbance_field=extra)
    return replace(session, others=(stream, *session.others)), replace(truth, mag=mt)


def _distort(ideal: np.ndarray, t: np.ndarray, m1: SensorModel, m2: SensorModel | None,
             t_change: float | None) -> np.ndarray:
    raw = m1.invert(ideal)
    if m2 is not None and t_change is not None:
        after = t >= t_change
        raw[after] = m2.invert(ideal[after])
    return raw


def _rescale(m: SensorModel | None, per_unit: float, offset: float, g: float
             ) -> SensorModel | None:
    """The same sensor with its raw output in other units: raw' = per_unit * raw + offset,
    calibrated output multiplied by g."""
    if m is None:
        return None
    return SensorModel(T=m.T, K=m.K * g / per_unit, b=m.b * per_unit + offset)


def thesis_experiment(seed: int = 0, noise: float = 0.1, n_vectors: int = 12, repeats: int = 100
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, SensorModel]:
    """The synthetic experiment of thesis ch. 5 (method.md §6).

    ``raw = (R E)^-1 (ideal + B)`` with the thesis's R, E, B, 12 random unit vectors repeated
    100 times and white noise of ``noise`` (10 %) per axis. In the M2 convention that is
    ``T K = R E`` and ``b = (R E)^-1 B``. Returns the raw samples, the static blocks (one per
    vector), the true (R, E, B) flattened, and the true M2 model.
    """
    rng = np.random.default_rng(seed)
    R = np.array([[1.0, 0.2, 0.4], [0.0, 1.0, 0.3], [0.0, 0.0, 1.0]])
    E = np.diag([1.2, 0.8, 1.3])
    B = np.array([0.5, -0.3, 0.2])
    v = rng.standard_normal((n_vectors, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    ideal = np.repeat(v, repeats, axis=0)
    RE = R @ E
    raw = np.linalg.solve(RE, (ideal + B).T).T + rng.normal(0, noise, ideal.shape)
    edges = np.arange(n_vectors + 1) * repeats
    blocks = np.column_stack([edges[:-1], edges[1:]])
    model = SensorModel(T=R, K=np.diag(E).copy(), b=np.linalg.solve(RE, B))
    return raw, blocks, np.r_[R[0, 1], R[0, 2], R[1, 2], np.diag(E), B], model
