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
    triads: tuple[TriadTruth, ...] = ()  # the session's other accelerometer triads (§11)
    temperature: TemperatureProfile | None = None  # the bias's drift with heat (§12)
    acc_range: float | None = None  # the first accelerometer's clip level, raw unit (M18)
    shake: float = 0.0  # peak linear acceleration during the turns, g

    def to_dict(self) -> dict:
        def m(model: SensorModel | None) -> dict | None:
            if model is None:
                return None
            return {"T": model.T.tolist(), "K": model.K.tolist(), "b": model.b.tolist()}

        return {"accelerometer": m(self.acc), "gyroscope": m(self.gyro),
                "accelerometer_after_change": m(self.acc2), "gyroscope_after_change": m(self.gyro2),
                "t_change": self.t_change, "gyro_drift": self.gyro_drift.tolist(), "g": self.g,
                "still_intervals": self.pose_times.tolist(),
                "model": "a = T K (a_raw - b); w = T_g K_g (w_raw - b_g) (method.md M2, M4)"
                } | ({} if self.mag is None else {"magnetometer": self.mag.to_dict()}) | (
                    {"triads": [t.to_dict() for t in self.triads]} if self.triads else {}) | (
                    {"temperature": self.temperature.to_dict()} if self.temperature else {}) | (
                    {"accelerometer_range": self.acc_range} if self.acc_range else {}) | (
                    {"shake_g": self.shake} if self.shake else {})

    def acc_bias_at(self, temp: np.ndarray) -> np.ndarray:
        """(N, 3) the accelerometer's true bias (raw unit) at temperatures ``temp`` (M16)."""
        extra = 0.0 if self.temperature is None else self.temperature.acc_drift(temp)
        return self.acc.b + extra * self.g

    def gyro_bias_at(self, temp: np.ndarray) -> np.ndarray:
        """(N, 3) the gyroscope's true bias (rad/s) at temperatures ``temp`` (M16)."""
        extra = 0.0 if self.temperature is None else self.temperature.gyro_drift(temp)
        return self.gyro.b + extra


@dataclass(frozen=True)
class TemperatureProfile:
    """The device's temperature over a session and what it does to the biases (method.md
    §12, M16): a linear ramp from ``start`` to ``end`` deg C (``steps`` > 0: that many equal
    steps instead), logged at ``rate`` Hz with ``noise`` deg C; the accelerometer's bias moves
    by ``sum_j acc[j-1] (T - ref)^j`` g and the gyroscope's by ``sum_j gyro[j-1] (T - ref)^j``
    rad/s, each a (p, 3) array of coefficients per deg C^j (p the true order)."""

    start: float = 15.0
    end: float = 45.0
    acc: tuple[tuple[float, float, float], ...] = ((4e-4, -3e-4, 2e-4), (1e-5, 1.5e-5, -1e-5))
    gyro: tuple[tuple[float, float, float], ...] = ((1e-4, -8e-5, 6e-5), (3e-6, -2e-6, 4e-6))
    ref: float = 30.0
    rate: float = 2.0
    noise: float = 0.05
    steps: int = 0
    back: bool = False  # up to ``end`` in the first half, back down to ``start`` in the second
    # Added to the bias while cooling (g, rad/s): a hysteresis no polynomial in T models.
    acc_hysteresis: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # The accelerometer's scales: K(T) = K (1 + acc_scale (T - ref)), relative per deg C.
    acc_scale: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gyro_hysteresis: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # The second triad's own (a2, and its IMU's gyroscope g2), as ``acc`` and ``gyro`` are the
    # first's; empty: it does not drift.
    acc2: tuple[tuple[float, float, float], ...] = ()
    gyro2: tuple[tuple[float, float, float], ...] = ()

    def cooling(self, t: np.ndarray, duration: float) -> np.ndarray:
        """(N,) True where the temperature is falling (the second half of a ``back`` ramp)."""
        return np.asarray(t) > duration / 2 if self.back else np.zeros(len(t), bool)

    def at(self, t: np.ndarray, duration: float) -> np.ndarray:
        """The true temperature at times ``t`` (deg C)."""
        frac = np.clip(t / max(duration, 1e-9), 0.0, 1.0)
        if self.back:
            frac = 1.0 - np.abs(2.0 * frac - 1.0)
        if self.steps > 0:
            frac = np.minimum(np.floor(frac * self.steps), self.steps - 1) / max(self.steps - 1, 1)
        return self.start + (self.end - self.start) * frac

    @staticmethod
    def _poly(coefs: tuple, temp: np.ndarray) -> np.ndarray:
        c = np.asarray(coefs, float).reshape(-1, 3)
        dt = np.asarray(temp, float).reshape(-1)
        return sum(c[j][None, :] * dt[:, None] ** (j + 1) for j in range(len(c)))

    def acc_drift(self, temp: np.ndarray) -> np.ndarray:
        return self._poly(self.acc, np.asarray(temp) - self.ref)

    def gyro_drift(self, temp: np.ndarray) -> np.ndarray:
        return self._poly(self.gyro, np.asarray(temp) - self.ref)

    def acc2_drift(self, temp: np.ndarray) -> np.ndarray:
        """(N, 3) the second triad's bias change at ``temp``, g."""
        return self._poly(self.acc2, np.asarray(temp) - self.ref)

    def gyro2_drift(self, temp: np.ndarray) -> np.ndarray:
        """(N, 3) the second triad's gyroscope's bias change at ``temp``, rad/s."""
        return self._poly(self.gyro2, np.asarray(temp) - self.ref)

    def to_dict(self) -> dict:
        return {"start_degC": self.start, "end_degC": self.end, "steps": self.steps,
                "back": self.back, "acc_hysteresis_g": list(self.acc_hysteresis),
                "acc_scale_per_degC": list(self.acc_scale),
                "gyro_hysteresis_rad_s": list(self.gyro_hysteresis),
                "reference_degC": self.ref, "acc_bias_coefficients_g": [list(c) for c in self.acc],
                "gyro_bias_coefficients_rad_s": [list(c) for c in self.gyro],
                "a2_bias_coefficients_g": [list(c) for c in self.acc2],
                "g2_bias_coefficients_rad_s": [list(c) for c in self.gyro2],
                "model": "b(T) = b + sum_j c_j (T - reference)^j (method.md M16)"}


@dataclass(frozen=True)
class SecondTriad:
    """A second accelerometer triad in the same device (method.md §11): turned by a random
    rotation of ``rotation_deg`` about a random axis from the first, clipped at ``range_g``, with
    its own errors, noise (g per sample), rate and clock (started a random fraction of a sample
    late)."""

    rotation_deg: float = 3.0
    range_g: float = 8.0
    noise: float = 0.006
    rate: float | None = None  # Hz; None: the first triad's
    mis: float = 0.01
    scale: float = 0.03
    bias: float = 0.05
    gyro: bool = False  # a gyroscope in the same IMU (its frame the triad's), named g2
    gyro_noise: float = 0.004  # rad/s per sample
    # On the first triad's timestamps (one table's rows) instead of a clock of its own.
    same_clock: bool = False


@dataclass(frozen=True)
class TriadTruth:
    """What made a second triad: ``u = R v`` takes its calibrated frame to the first's (M12)."""

    name: str
    model: SensorModel  # M2 in the triad's raw unit
    R: np.ndarray  # (3, 3) to the first triad's frame
    range: float  # clipping level, in the raw unit
    noise: float  # per sample, g
    gyro: SensorModel | None = None  # M4 of its IMU's gyroscope (rad/s), if it has one

    def to_dict(self) -> dict:
        g = None if self.gyro is None else {"T": self.gyro.T.tolist(), "K": self.gyro.K.tolist(),
                                            "b": self.gyro.b.tolist()}
        return {"name": self.name, "T": self.model.T.tolist(), "K": self.model.K.tolist(),
                "b": self.model.b.tolist(), "rotation_to_reference": self.R.tolist(),
                "range": self.range, "noise_g": self.noise, "gyroscope": g}


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
    second_acc: SecondTriad | tuple[SecondTriad, ...] | None = None,
    temperature: TemperatureProfile | None = None,
    acc_range: float | None = None,
    shake: float = 0.0,
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
    ``second_acc`` adds a second accelerometer triad (``Session.others``, named ``a2`` as a
    table's a2x… columns are; a tuple of them: a2, a3, ...) and its truth (``Truth.triads``),
    drawn from a generator of its own: the first triad and the gyroscope are the same as
    without it. ``temperature`` makes
    the biases drift with a temperature profile and adds its stream (``temp``, in
    ``Session.others``); the noise drawn is the same as without it. ``acc_range`` (g) clips
    the first accelerometer there (a low-range part, method.md §11, M18); ``shake`` (g) adds a
    linear acceleration of that peak during every turn (:func:`specific_force`), which every
    accelerometer triad reads: drawn apart, so that 0 leaves the session as it was.
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
    ideal_a = quat.rotate_inverse(q_a, specific_force(motion, t_a, shake, seed) if shake
                                  else np.array([0.0, 0.0, 1.0]))
    _, w = motion.at(t_g)

    raw_a = _distort(ideal_a, t_a, acc_truth, acc2, t_change)
    raw_a += rng.normal(0, acc_noise, raw_a.shape)
    if acc_drift:
        way = np.random.default_rng([seed, 2]).normal(0, 1, 3)
        raw_a += np.outer(t_a / max(duration, 1e-9), acc_drift * way / np.linalg.norm(way))
    raw_g = _distort(w, t_g, gyro_truth, gyro2, t_change) + drift * t_g[:, None]
    raw_g += rng.normal(0, gyro_noise, raw_g.shape)
    temp_stream = None
    if temperature is not None:  # M16: the bias moves with heat, in g and rad/s
        heat_a = temperature.at(t_a, duration)
        # K(T): the raw reading about the bias shrinks as the scale grows (M2 inverted)
        raw_a = acc_truth.b + (raw_a - acc_truth.b) / (
            1.0 + np.asarray(temperature.acc_scale)[None, :] * (heat_a - temperature.ref)[:, None])
        raw_a += temperature.acc_drift(heat_a)
        raw_g += temperature.gyro_drift(temperature.at(t_g, duration))
        raw_a += np.outer(temperature.cooling(t_a, duration), temperature.acc_hysteresis)
        raw_g += np.outer(temperature.cooling(t_g, duration), temperature.gyro_hysteresis)
        t_t = np.arange(0.0, duration, 1.0 / temperature.rate)
        heat = temperature.at(t_t, duration) + np.random.default_rng([seed, 3]).normal(
            0, temperature.noise, len(t_t))
        temp_stream = Stream("temp", "temp", t_t, heat[:, None], "degC",
                             "synthetic temperature", time_source="the session's clock")

    if acc_range is not None:  # the part's range: flat beyond it (in g, before the unit)
        raw_a = np.clip(raw_a, -acc_range, acc_range)
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

    others, triads = (), ()
    specs = (second_acc,) if isinstance(second_acc, SecondTriad) else (second_acc or ())
    for i, spec in enumerate(specs):  # a2 (g2), a3 (g3), ...: each from a generator of its own
        streams, tt = _second_triad(motion, spec, seed, acc_rate, acc_unit, number=i + 2,
                                    shake=shake, t_first=t_a, temperature=temperature)
        others, triads = others + streams, triads + (tt,)
    if temp_stream is not None:
        if acc_unit == "counts" or gyro_unit == "counts":
            raise ValueError("a temperature profile is made in g or m/s^2 and rad/s")
        others += (temp_stream,)
    session = Session(acc=raw_a, t_acc=t_a, gyro=raw_g, t_gyro=t_g, acc_unit=acc_unit,
                      gyro_unit="counts" if gyro_unit == "counts" else "rad/s",
                      source=f"synthetic(seed={seed}, poses={poses})", others=others)
    truth = Truth(acc=acc_truth, gyro=gyro_truth, acc2=acc2, gyro2=gyro2, t_change=t_change,
                  gyro_drift=drift, g=g, pose_times=motion.still, triads=triads,
                  temperature=temperature,
                  acc_range=None if acc_range is None else float(acc_range) * g,
                  shake=float(shake))
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


SHAKE_HZ = 4.0  # the shake's frequency during a turn


def specific_force(motion: Motion, t: np.ndarray, shake: float, seed: int) -> np.ndarray:
    """(N, 3) the specific force in the world frame, g: gravity's ``e_z``, plus with ``shake``
    > 0 a linear acceleration during every turn, ``shake sin^2(pi tau) sin(2 pi f (t - t_0))``
    along a direction drawn per turn (its own generator, ``[seed, 5]``; ``f`` =
    :data:`SHAKE_HZ`, ``tau`` the turn's fraction done)."""
    out = np.zeros((len(t), 3))
    out[:, 2] = 1.0
    if not shake:
        return out
    way = np.random.default_rng([seed, 5]).normal(0, 1, (max(len(motion.q) - 1, 1), 3))
    way /= np.linalg.norm(way, axis=1, keepdims=True)
    k = np.clip(np.searchsorted(motion.still[:, 0], t, side="right") - 1, 0, len(motion.q) - 1)
    moving = (t >= motion.still[k, 1]) & (k < len(motion.q) - 1)
    km = k[moving]
    t0, t1 = motion.still[km, 1], motion.still[km + 1, 0]
    tau = (t[moving] - t0) / (t1 - t0)
    size = shake * np.sin(np.pi * tau) ** 2 * np.sin(2 * np.pi * SHAKE_HZ * (t[moving] - t0))
    out[moving] += way[km] * size[:, None]
    return out


def _second_triad(motion: Motion, spec: SecondTriad, seed: int, acc_rate: float,
                  acc_unit: str, number: int = 2, shake: float = 0.0,
                  t_first: np.ndarray | None = None,
                  temperature: TemperatureProfile | None = None
                  ) -> tuple[tuple[Stream, ...], TriadTruth]:
    """The second accelerometer's stream (and its gyroscope's) and truth (method.md §11, M12:
    ``u = R v``; the gyroscope in the same frame, so M14's rotation is ``R`` too). With
    ``temperature``, the second triad (``number`` 2) drifts by its own coefficients
    (``acc2``, ``gyro2``) at the device's temperature, drawn nothing more."""
    if acc_unit not in ("g", "m/s^2"):
        raise ValueError(f"a second triad is made in g or m/s^2, not {acc_unit!r}")
    rng = np.random.default_rng([seed, 2] if number == 2 else [seed, 2, number])
    axis = rng.normal(0, 1, 3)
    axis /= np.linalg.norm(axis)
    R = quat.to_matrix(quat.from_rotvec(axis[None] * np.radians(spec.rotation_deg)))[0]
    model = random_acc_model(rng, spec.mis, spec.scale, spec.bias)
    rate = spec.rate or acc_rate
    duration = float(motion.still[-1, 1])
    t = (rng.uniform(0, 1) + np.arange(int(duration * rate) - 1)) / rate
    if spec.same_clock:
        t = t_first
    q, w = motion.at(t)
    up = specific_force(motion, t, shake, seed) if shake else np.array([0.0, 0.0, 1.0])
    v = quat.rotate_inverse(q, up) @ R  # v = R' u, row by row
    raw = model.invert(v) + rng.normal(0, spec.noise, v.shape)
    heat = None if temperature is None or number != 2 else temperature.at(t, duration)
    if heat is not None:  # M16 for this triad: its own bias in temperature, in g
        raw += temperature.acc2_drift(heat)
    raw = np.clip(raw, -spec.range_g, spec.range_g)  # the triad's range: flat beyond it
    g = STANDARD_GRAVITY if acc_unit == "m/s^2" else 1.0
    raw *= g
    model = _rescale(model, g, 0.0, g)
    a, g_name = f"a{number}", f"g{number}"
    streams = (Stream("acc", a, t, raw, acc_unit, f"synthetic accelerometer {number} ({a}x, "
                      f"{a}y, {a}z)", time_source="its own clock"),)
    gyro = None
    if spec.gyro:  # drawn after everything above: the accelerometer is the same without it
        gyro = random_gyro_model(rng)
        raw_g = gyro.invert(w @ R) + rng.normal(0, spec.gyro_noise, w.shape)
        if heat is not None:
            raw_g += temperature.gyro2_drift(heat)
        streams += (Stream("gyro", g_name, t, raw_g, "rad/s", f"synthetic gyroscope {number} "
                           f"({g_name}x, {g_name}y, {g_name}z)", time_source="its own clock"),)
    return streams, TriadTruth(name=a, model=model, R=R, range=spec.range_g * g,
                               noise=spec.noise, gyro=gyro)


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
