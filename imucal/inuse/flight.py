"""Synthetic flights (method.md §10, issue 26 item 4): a multirotor's log with known drift.

The vehicle rests on the ground, motors off (the only still moments of a flight log), then its
motors idle (vibration that is not motion: the IMU does not move), it takes off, flies (tilts of
up to 25 deg, turns about the vertical, climbs and descents, the motors' vibration throughout),
lands (a touchdown's knock), idles and rests again; as many flights as the minutes hold.

In flight a multirotor's specific force lies along its thrust, the body's z axis, whatever its
tilt, so the accelerometer reads ``(0, 0, (1 + a_z) / cos(tilt))`` g plus vibration; the body
rate is the exact difference of the closed-form orientation, as in
:mod:`imucal.inuse.everyday`. On the ground the vehicle stands level but for a constant tilt
of 1-3 deg: its rests all give one orientation, so a flight log tells the gyroscope's bias and
not the accelerometer's biases or scales (no axis has moments on both sides).
"""

from __future__ import annotations

import numpy as np

from imucal.inuse.truth import Drift, EverydayTruth, H
from imucal.models import SensorModel
from imucal.numerics import quaternion as quat
from imucal.session import Session
from imucal.synth import random_acc_model, random_gyro_model

REST_S = (25.0, 45.0)  # motors off on the ground, s
IDLE_S = (4.0, 8.0)  # motors idling before take-off and after landing
FLIGHT_S = (60.0, 150.0)
RAMP_S = 3.0  # take-off and landing: the flight's motions ramp in and out
IDLE_G = (0.02, 0.05)  # vibration's amplitude per axis, idling and flying (g)
FLYING_G = (0.08, 0.2)
VIB_RAD_S = (0.02, 0.1)  # the gyroscope's share of it, rad/s
TOUCHDOWN_G = (1.0, 2.0)
TOUCHDOWN_S = 0.03


def make_flight(minutes: float, rng: np.random.Generator, drift: Drift, rate: float,
                acc_noise: float, gyro_noise: float, stored_acc: SensorModel | None = None,
                stored_gyro: SensorModel | None = None, seed: int = 0
                ) -> tuple[Session, EverydayTruth]:
    """A flight log of about ``minutes`` and its truth (``still``: the rests, motors off;
    ``disturbed``: the motors on, idling or flying; ``taps``: the touchdowns)."""
    rests, flights, idles = _timeline(rng, minutes * 60.0)
    t = np.arange(int(rests[-1, 1] * rate)) / rate
    stored_acc = stored_acc or random_acc_model(rng)
    stored_gyro = stored_gyro or random_gyro_model(rng)
    acc_model, gyro_model = drift.apply(stored_acc, stored_gyro)

    tilt0 = np.radians(rng.uniform(1, 3)) * _unit(rng, 2)  # the ground's tilt (x, y)
    f_att = rng.uniform(0.05, 0.3, (3, 2))
    ph = rng.uniform(0, 2 * np.pi, (3, 2))
    amp = np.array([np.radians(12.5), np.radians(12.5), 1.5])  # roll, pitch (x2), yaw
    f_up, ph_up = rng.uniform(0.05, 0.2, 2), rng.uniform(0, 2 * np.pi, 2)

    def envelope(tt: np.ndarray) -> np.ndarray:
        return _ramps(tt, flights)

    def orientation(tt: np.ndarray) -> np.ndarray:
        s = np.sin(2 * np.pi * f_att[None] * tt[:, None, None] + ph[None]).sum(axis=2)
        att = envelope(tt)[:, None] * s * amp  # roll, pitch, yaw
        yaw = quat.from_rotvec(np.column_stack([np.zeros_like(tt), np.zeros_like(tt),
                                                att[:, 2]]))
        level = quat.from_rotvec(np.column_stack([att[:, 0] + tilt0[0], att[:, 1] + tilt0[1],
                                                  np.zeros_like(tt)]))
        return quat.multiply(yaw, level)

    q = orientation(t)
    w = quat.to_rotvec(quat.multiply(quat.conjugate(orientation(t - H)), orientation(t + H)))
    w /= 2 * H
    env = envelope(t)
    up = env * 0.15 * np.sin(2 * np.pi * f_up[:, None] * t + ph_up[:, None]).sum(axis=0) / 2
    ground = quat.rotate_inverse(q, np.array([0.0, 0.0, 1.0]))  # on the ground: gravity
    thrust = np.zeros_like(ground)
    thrust[:, 2] = (1.0 + up) / ground[:, 2]  # flying: along the thrust (R_zz = cos tilt)
    ideal_a = (1.0 - env)[:, None] * ground + env[:, None] * thrust  # blended over the ramps
    on = np.vstack([idles, flights])
    ideal_a, w = _vibrate(rng, t, ideal_a, w, idles, IDLE_G)
    ideal_a, w = _vibrate(rng, t, ideal_a, w, flights, FLYING_G)
    taps = flights[:, 1] - 0.5 * RAMP_S  # a touchdown, as the landing's ramp ends
    k = np.searchsorted(taps, t, side="right") - 1
    dt = np.where(k >= 0, t - taps[np.maximum(k, 0)], np.inf)
    knock = (dt >= 0) & (dt < TOUCHDOWN_S)
    size = rng.uniform(*TOUCHDOWN_G, len(taps))
    ideal_a[knock, 2] += size[k[knock]] * np.sin(np.pi * dt[knock] / TOUCHDOWN_S)

    raw_a = acc_model.invert(ideal_a) + rng.normal(0, acc_noise, ideal_a.shape)
    raw_g = gyro_model.invert(w) + rng.normal(0, gyro_noise, w.shape)
    session = Session(acc=raw_a, t_acc=t, gyro=raw_g, t_gyro=t, acc_unit="g",
                      gyro_unit="rad/s", source=f"synthetic(flight, seed={seed})")
    truth = EverydayTruth(activity="flight", stored_acc=stored_acc, stored_gyro=stored_gyro,
                          acc=acc_model, gyro=gyro_model, drift=drift, still=rests, taps=taps,
                          disturbed=on[np.argsort(on[:, 0])], acc_noise=acc_noise,
                          gyro_noise=gyro_noise, rate=rate)
    return session, truth


def _unit(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.normal(size=n)
    return v / np.linalg.norm(v)


def _timeline(rng: np.random.Generator, total: float
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """[t0, t1) of the rests, the flights and the idling: rest, idle, flight, idle, rest, ...
    until ``total`` s (one flight at least)."""
    rests, flights, idles = [], [], []
    s = 0.0
    while True:
        r = rng.uniform(*REST_S)
        rests.append((s, s + r))
        s += r
        if flights and s >= total:
            break
        i0, f, i1 = rng.uniform(*IDLE_S), rng.uniform(*FLIGHT_S), rng.uniform(*IDLE_S)
        idles.append((s, s + i0))
        flights.append((s + i0, s + i0 + f))
        idles.append((s + i0 + f, s + i0 + f + i1))
        s += i0 + f + i1
    return (np.array(rests), np.array(flights).reshape(-1, 2),
            np.array(idles).reshape(-1, 2))


def _ramps(tt: np.ndarray, flights: np.ndarray) -> np.ndarray:
    """1 in flight, 0 on the ground, by the minimum-jerk ramp over RAMP_S at each end."""
    k = np.clip(np.searchsorted(flights[:, 0], tt, side="right") - 1, 0, len(flights) - 1)
    a, b = flights[k, 0], flights[k, 1]
    inside = (tt >= a) & (tt < b)
    x = np.clip(np.minimum(tt - a, b - tt) / RAMP_S, 0.0, 1.0)
    return np.where(inside, x**3 * (10 - 15 * x + 6 * x**2), 0.0)


def _vibrate(rng: np.random.Generator, t: np.ndarray, acc: np.ndarray, w: np.ndarray,
             spans: np.ndarray, amp_g: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """The motors' vibration over ``spans``: per axis a blade-pass tone (35-48 Hz, below a
    100 Hz log's Nyquist; faster ones alias to such) and its aliased harmonic, the IMU not
    moving; the gyroscope feels a fraction of it."""
    acc, w = acc.copy(), w.copy()
    for a, b in spans:
        on = (t >= a) & (t < b)
        f = rng.uniform(35, 48)
        f2 = abs(2 * f - 100.0)  # the harmonic as a 100 Hz log sees it
        ph = rng.uniform(0, 2 * np.pi, (2, 3))
        tone = (np.sin(2 * np.pi * f * t[on, None] + ph[0])
                + 0.5 * np.sin(2 * np.pi * f2 * t[on, None] + ph[1]))
        acc[on] += rng.uniform(*amp_g, 3) * tone
        w[on] += rng.uniform(*VIB_RAD_S, 3) * tone
    return acc, w
