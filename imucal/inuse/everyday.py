"""Synthetic everyday use (method.md §10): a recording of ordinary use with known drift.

The device rests in random orientations for a few seconds now and then (``walk``, ``jumps``) or
lies on a desk face by face (``desk``), and between the rests it is carried: the orientation is
the scripted rests and turns of :func:`imucal.synth.make_motion` with an activity on top (an
arm's swing and a step's bounce, a jump's push and landing). A standing person sways: a tilt of
a few tenths of a degree about the horizontal, always on. Taps (20 ms pulses, not motion) come in
bursts while the device is held, and typing vibrates the desk. The orientation is closed-form in
time, ``q(t) = exp(psi(t)) (x) q_base(t)`` with ``psi`` a world-frame rotation vector, so the body
rate is the exact difference ``log(q(t - h)^-1 q(t + h)) / 2h`` (h = 0.1 ms) at every sample.

The raw signals come from the *current* sensor (the stored calibration with the chosen drift);
the truth keeps both, and where the device really lay still.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from imucal.inuse.flight import make_flight
from imucal.inuse.truth import Drift, EverydayTruth, H
from imucal.models import SensorModel
from imucal.numerics import quaternion as quat
from imucal.session import Session
from imucal.synth import make_motion, random_acc_model, random_gyro_model

ACTIVITIES = ("walk", "jumps", "desk", "flight")  # flight: imucal.inuse.flight
TAP_S = 0.02  # a tap's pulse, s
EDGE_S = 1.0  # an activity's ramp in and out at each end of a carry, s


# Per activity: seconds at rest (each rest drawn 0.8-1.2 times this), seconds carried between
# rests, and whether a rest is held in the hand (sway) or lies on a desk.
_PLAN = {"walk": (5.0, 30.0, True), "jumps": (4.0, 12.0, True), "desk": (40.0, 3.0, False)}


def make_everyday(activity: str = "walk", minutes: float = 10.0, seed: int = 0,
                  drift: Drift | None = None, rate: float = 100.0, acc_noise: float = 0.003,
                  gyro_noise: float = 0.003, sway_deg: float = 0.25, tapping: float = 0.2,
                  stored_acc: SensorModel | None = None, stored_gyro: SensorModel | None = None,
                  ) -> tuple[Session, EverydayTruth]:
    """A recording of ``minutes`` of ``activity`` ("walk", "jumps", "desk", "flight") and its
    truth.

    ``tapping`` is the fraction of the hand-held rests spent being tapped instead (a burst of
    taps 0.3-1.2 s apart: the device is still but for the taps, and no moment may come of it);
    on the desk, the rests are cut by typing (1-4 s of 30 Hz vibration, 20-40 mg) and a tap or
    two. ``sway_deg`` is the amplitude of the sway's tilt about each horizontal axis."""
    if activity not in ACTIVITIES:
        raise ValueError(f"activity must be one of {ACTIVITIES}, got {activity!r}")
    rng = np.random.default_rng([seed, ACTIVITIES.index(activity)])
    if activity == "flight":  # a vehicle: its own module
        return make_flight(minutes, rng, drift or Drift(), rate, acc_noise, gyro_noise,
                           stored_acc, stored_gyro, seed)
    hold, carry, held = _PLAN[activity]
    poses = max(2, int(round((minutes * 60.0 + carry) / (hold + carry))))
    motion = make_motion(rng, poses, hold, carry, hold)
    if activity == "desk":  # lying on a face, turned about the vertical at random
        motion = _on_faces(motion, rng)
    duration = float(motion.still[-1, 1])
    t = np.arange(int(duration * rate)) / rate
    stored_acc = stored_acc or random_acc_model(rng)
    stored_gyro = stored_gyro or random_gyro_model(rng)
    drift = drift or Drift()
    acc_model, gyro_model = drift.apply(stored_acc, stored_gyro)

    phases = rng.uniform(0, 2 * np.pi, 8)
    sway = _sway(rng, sway_deg if held else 0.0)
    carrying = _carrying(motion)

    def orientation(tt: np.ndarray) -> np.ndarray:
        q_base, _ = motion.at(tt)
        psi = sway(tt) + carrying(tt)[:, None] * _activity_rotation(activity, tt, phases)
        return quat.multiply(quat.from_rotvec(psi), q_base)

    q = orientation(t)
    w = quat.to_rotvec(quat.multiply(quat.conjugate(orientation(t - H)), orientation(t + H)))
    w /= 2 * H
    lin = carrying(t)[:, None] * _activity_acceleration(activity, t, phases)
    if held:  # the sway's own acceleration: half a mg, horizontal
        lin[:, :2] += 5e-4 * np.sin(2 * np.pi * 0.35 * t[:, None] + phases[:2])
    ideal_a = quat.rotate_inverse(q, np.array([0.0, 0.0, 1.0]) + lin)

    rests = motion.still.copy()
    taps, disturbed = _disturbances(rng, rests, activity, tapping)
    ideal_a, w = _add_taps(rng, t, ideal_a, w, taps)
    if activity == "desk":
        ideal_a = _add_typing(rng, t, q, ideal_a, disturbed)
    still = _still_intervals(rests, disturbed)

    raw_a = acc_model.invert(ideal_a) + rng.normal(0, acc_noise, ideal_a.shape)
    raw_g = gyro_model.invert(w) + rng.normal(0, gyro_noise, w.shape)
    session = Session(acc=raw_a, t_acc=t, gyro=raw_g, t_gyro=t, acc_unit="g",
                      gyro_unit="rad/s", source=f"synthetic({activity}, seed={seed})")
    truth = EverydayTruth(activity=activity, stored_acc=stored_acc, stored_gyro=stored_gyro,
                          acc=acc_model, gyro=gyro_model, drift=drift, still=still, taps=taps,
                          disturbed=disturbed, acc_noise=acc_noise, gyro_noise=gyro_noise,
                          rate=rate)
    return session, truth


def _on_faces(motion, rng: np.random.Generator):
    """The same rests and turns with each rest on one of the six faces (a random turn about the
    vertical): a desk's orientations."""
    faces = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [1, 1, 0, 0], [1, -1, 0, 0], [1, 0, 1, 0],
                      [1, 0, -1, 0]], float)
    faces /= np.linalg.norm(faces, axis=1, keepdims=True)
    n = len(motion.q)
    pick = np.r_[rng.permutation(6), rng.integers(0, 6, max(0, n - 6))][:n]
    yaw = quat.from_rotvec(np.column_stack([np.zeros(n), np.zeros(n),
                                            rng.uniform(-np.pi, np.pi, n)]))
    q = quat.multiply(yaw, faces[pick])
    rel = quat.multiply(quat.conjugate(q[:-1]), q[1:])
    rv = quat.to_rotvec(rel)
    angle = np.linalg.norm(rv, axis=1)
    return replace(motion, q=q, axis=rv / np.maximum(angle, 1e-12)[:, None], angle=angle)


def _sway(rng: np.random.Generator, amp_deg: float):
    """A standing person's sway: a world-frame tilt about x and y, two frequencies each
    (0.15-0.6 Hz), and a fiftieth of it about the vertical."""
    amp = np.radians(amp_deg)
    f = rng.uniform(0.15, 0.6, (3, 2))
    ph = rng.uniform(0, 2 * np.pi, (3, 2))
    scale = np.array([amp, amp, amp / 50]) / np.sqrt(2)

    def at(tt: np.ndarray) -> np.ndarray:
        s = np.sin(2 * np.pi * f[None] * tt[:, None, None] + ph[None]).sum(axis=2)
        return s * scale

    return at


def _carrying(motion):
    """1 while carried (between rests), ramping in and out over EDGE_S by the minimum-jerk
    profile, 0 at rest: the activity stops before the device comes to rest."""
    starts, ends = motion.still[1:, 0], motion.still[:-1, 1]

    def at(tt: np.ndarray) -> np.ndarray:
        k = np.clip(np.searchsorted(ends, tt, side="right") - 1, 0, len(ends) - 1)
        a, b = ends[k], starts[k]
        inside = (tt >= a) & (tt < b)
        ramp = np.clip(np.minimum(tt - a, b - tt) / EDGE_S, 0.0, 1.0)
        s = ramp**3 * (10 - 15 * ramp + 6 * ramp**2)  # minimum jerk, as the turns
        return np.where(inside, s, 0.0)

    return at


def _activity_rotation(activity: str, tt: np.ndarray, ph: np.ndarray) -> np.ndarray:
    """The activity's world-frame rotation vector while carried: an arm's swing (walk, 1 Hz,
    0.4 rad), a jump's wobble (1.6 Hz, 0.1 rad), a hand's pick-up (desk: none)."""
    out = np.zeros((len(tt), 3))
    if activity == "walk":
        out[:, 0] = 0.4 * np.sin(2 * np.pi * 1.0 * tt + ph[2])
        out[:, 2] = 0.15 * np.sin(2 * np.pi * 1.0 * tt + ph[3])
    elif activity == "jumps":
        out[:, 0] = 0.1 * np.sin(2 * np.pi * 1.6 * tt + ph[2])
        out[:, 1] = 0.1 * np.sin(2 * np.pi * 1.6 * tt + ph[3])
    return out


def _activity_acceleration(activity: str, tt: np.ndarray, ph: np.ndarray) -> np.ndarray:
    """The activity's world-frame linear acceleration while carried, g: a step's bounce (walk:
    0.3 g at 2 Hz up, 0.1 g at 1 Hz forward), a jump's push and landing (1.2 g at 1.6 Hz and its
    harmonic), a hand's carry (desk: 0.1 g)."""
    out = np.zeros((len(tt), 3))
    if activity == "walk":
        out[:, 2] = 0.3 * np.sin(2 * np.pi * 2.0 * tt + ph[4])
        out[:, 0] = 0.1 * np.sin(2 * np.pi * 1.0 * tt + ph[5])
    elif activity == "jumps":
        out[:, 2] = (0.9 * np.sin(2 * np.pi * 1.6 * tt + ph[4])
                     + 0.4 * np.sin(2 * np.pi * 3.2 * tt + 2 * ph[4]))
    else:
        out[:, 0] = 0.1 * np.sin(2 * np.pi * 0.5 * tt + ph[5])
    return out


def _disturbances(rng: np.random.Generator, rests: np.ndarray, activity: str,
                  tapping: float) -> tuple[np.ndarray, np.ndarray]:
    """The taps' times and the disturbed stretches: a ``tapping`` share of the rests (after the
    first) tapped throughout (hand-held), or on the desk typing bursts and a tap now and then."""
    taps: list[np.ndarray] = []
    disturbed: list[tuple[float, float]] = []
    for a, b in rests[1:]:
        if activity != "desk":
            if rng.uniform() < tapping:
                gaps = rng.uniform(0.3, 1.2, int((b - a) / 0.3) + 2)
                times = a + 0.2 + np.cumsum(gaps)
                taps.append(times[times < b - 0.2])
                disturbed.append((a, b))
            continue
        s = a + rng.uniform(3, 10)
        while s < b - 2:  # typing bursts, 1-4 s, 3-12 s apart
            e = min(s + rng.uniform(1, 4), b)
            disturbed.append((s, e))
            s = e + rng.uniform(3, 12)
        if rng.uniform() < 0.5:
            tap = rng.uniform(a + 1, b - 1)
            taps.append(np.array([tap]))
            disturbed.append((tap, tap + TAP_S))
    taps_all = np.sort(np.concatenate(taps)) if taps else np.zeros(0)
    dist = np.array(sorted(disturbed), float).reshape(-1, 2)
    return taps_all, dist


def _add_taps(rng: np.random.Generator, t: np.ndarray, acc: np.ndarray, w: np.ndarray,
              taps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A half-sine pulse of TAP_S at each tap: 0.3-1.5 g along a random body direction and
    0.2-1 rad/s about another (a knock the sensor feels, not a motion it makes)."""
    if len(taps) == 0:
        return acc, w
    acc, w = acc.copy(), w.copy()
    k = np.searchsorted(taps, t, side="right") - 1
    near = k >= 0
    dt = np.where(near, t - taps[np.maximum(k, 0)], np.inf)
    on = near & (dt < TAP_S)
    d_acc = rng.normal(0, 1, (len(taps), 3))
    d_acc *= (rng.uniform(0.3, 1.5, len(taps)) / np.linalg.norm(d_acc, axis=1))[:, None]
    d_w = rng.normal(0, 1, (len(taps), 3))
    d_w *= (rng.uniform(0.2, 1.0, len(taps)) / np.linalg.norm(d_w, axis=1))[:, None]
    pulse = np.sin(np.pi * dt[on] / TAP_S)[:, None]
    acc[on] += pulse * d_acc[k[on]]
    w[on] += pulse * d_w[k[on]]
    return acc, w


def _add_typing(rng: np.random.Generator, t: np.ndarray, q: np.ndarray, acc: np.ndarray,
                disturbed: np.ndarray) -> np.ndarray:
    """30 Hz vibration of the desk (vertical, 20-40 mg) over each typing burst."""
    long = disturbed[disturbed[:, 1] - disturbed[:, 0] > 2 * TAP_S]
    if len(long) == 0:
        return acc
    k = np.searchsorted(long[:, 0], t, side="right") - 1
    on = (k >= 0) & (t < long[np.maximum(k, 0), 1])
    amp = rng.uniform(0.02, 0.04, len(long))
    vert = amp[k[on]] * np.sin(2 * np.pi * 30.0 * t[on])
    acc = acc.copy()
    acc[on] += quat.rotate_inverse(q[on], np.array([0.0, 0.0, 1.0])) * vert[:, None]
    return acc


def _still_intervals(rests: np.ndarray, disturbed: np.ndarray) -> np.ndarray:
    """The rests with the disturbed stretches cut out."""
    out = []
    for a, b in rests:
        cuts = disturbed[(disturbed[:, 1] > a) & (disturbed[:, 0] < b)]
        s = a
        for c0, c1 in cuts:
            if c0 > s:
                out.append((s, c0))
            s = max(s, c1)
        if b > s:
            out.append((s, b))
    return np.array(out, float).reshape(-1, 2)
