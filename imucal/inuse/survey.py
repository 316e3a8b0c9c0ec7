"""The still moments of a recording without a calibration of its device (method.md §10):
what ``imucal check --moments-only`` prints. Would this recording of ordinary use let
``check`` judge a calibration and ``refresh`` update one? That depends on the moments it
holds (how many, how long, in which orientations), not on the calibration's numbers, so it
can be told before the device has one.

The signals are read as they are, in the recording's own units (a calibration moves |g| and
the orientations by a few per cent at most, well inside the 10 % and 0.3 g the rules use), and
the sensor's noise, which a calibration stores, is learned from the recording's quietest
windows, as ``check`` does with a calibration that stores none. That is the sensor's noise
only if the recording rests somewhere: a log whose motors run from its first sample to its
last teaches the detector the vibration, and the survey says so when the level learned is
beyond what a MEMS accelerometer at rest shows. The gyroscope's rule (a mean rate below 3
deg/s) would refuse every moment of a gyroscope whose raw bias exceeds it (MEMS parts leave
the factory with several deg/s), so it is applied to the rate less the median of the moments'
mean rates, found by a first pass on the accelerometer alone."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from imucal.errors import ImucalError
from imucal.inuse.check import MIN_ACC_ORIENTATIONS, MIN_GYRO_STILL_S
from imucal.inuse.estimate import AXES, COVERAGE_G, MIN_ACC_MOMENTS, coverage
from imucal.inuse.moments import ModelRows, Moments, find_moments
from imucal.models import SensorModel
from imucal.session import STANDARD_GRAVITY, Session

# Above this white-noise density a "quietest" level is not an accelerometer at rest: MEMS
# parts at rest lie between 0.07 (LSM6DSO) and 0.4 mg/sqrt(Hz) (MPU-6050), ADXL345's z at
# about 0.45; the motors of a vehicle idling on the ground give several (a 100 Hz log, 20-50
# mg of vibration: 2-5 mg/sqrt(Hz)).
NOISE_CEILING_MG_RT_HZ = 1.0
SLOW_HZ = 20.0  # below, a 0.5 s window holds too few samples for a variance (M1)


@dataclass(frozen=True)
class Survey:
    """The moments found, the noise they were found against, and what they would suffice
    for (the rules of :mod:`imucal.inuse.check` and :mod:`imucal.inuse.refresh`)."""

    moments: Moments
    g: float  # |g| in the accelerometer's unit
    unit: str
    rate: float  # Hz
    duration: float  # s
    gyro: bool  # the gyroscope's moments were judged too (its unit known)
    noise_mg: float  # the accelerometer's noise per sample and axis learned, mg (nan: none)
    notes: tuple[str, ...]
    gyro_offset: np.ndarray  # (3,) rad/s: the median rate at rest taken off before the rule

    @property
    def rate_at_rest(self) -> np.ndarray | None:
        """(B, 3) rad/s: M10's rate at rest of each moment as recorded (the raw bias)."""
        return None if self.moments.rate is None else self.moments.rate + self.gyro_offset

    @property
    def noise_density(self) -> float:
        """mg/sqrt(Hz): ``sigma = N sqrt(rate)``, the convention of calib.json's noise."""
        return self.noise_mg / float(np.sqrt(self.rate))

    @property
    def still_s(self) -> float:
        return float(self.moments.durations.sum()) if self.moments.count else 0.0

    @property
    def axis_range(self) -> np.ndarray:
        """(3, 2): the lowest and highest mean reading along each axis over the moments, g."""
        if self.moments.count == 0:
            return np.full((3, 2), np.nan)
        u = self.moments.cal_mean / self.g
        return np.column_stack([u.min(axis=0), u.max(axis=0)])

    @property
    def covered(self) -> np.ndarray:
        """(3,) bool: the axes refresh would update (0.3 g both sides, MIN_ACC_MOMENTS)."""
        return coverage(self.moments, self.g) & (self.moments.count >= MIN_ACC_MOMENTS)

    @property
    def gyro_enough(self) -> bool:
        return self.gyro and self.still_s >= MIN_GYRO_STILL_S

    @property
    def acc_enough(self) -> bool:
        m = self.moments
        return m.count >= MIN_ACC_MOMENTS and m.orientations >= MIN_ACC_ORIENTATIONS

    @property
    def noise_plausible(self) -> bool:
        """The level learned could be a sensor's noise at rest (else it may be vibration)."""
        return not self.noise_density > NOISE_CEILING_MG_RT_HZ

    @property
    def exit_code(self) -> int:
        """0 when check could judge every sensor the recording holds, 2 when it would say
        cannot tell for one (check's own codes), or when the moments may be vibration."""
        enough = self.acc_enough and (self.gyro_enough or not self.gyro)
        return 0 if enough and self.noise_plausible else 2

    def to_dict(self) -> dict:
        m = self.moments
        rng = self.axis_range
        rate_deg = None if self.rate_at_rest is None else np.degrees(self.rate_at_rest)
        return {
            "exit_code": self.exit_code,
            "still_moments": {
                "count": m.count, "seconds": self.still_s, "orientations": m.orientations,
                "moments": [{"t": [float(a), float(b)], "seconds": float(b - a),
                             "mean_acc_g": (m.cal_mean[i] / self.g).tolist(),
                             "rate_at_rest_deg_s": None if rate_deg is None
                             else rate_deg[i].tolist()}
                            for i, (a, b) in enumerate(m.times)],
                "detector": {"window": m.window, "min_len": m.min_len, "k": m.k,
                             "reference_from": m.level_from, "rejected": m.rejected}},
            "noise_learned": {"mg_per_sample": _finite(self.noise_mg),
                              "mg_per_sqrt_hz": _finite(self.noise_density),
                              "plausible_at_rest": self.noise_plausible},
            "coverage": {a: {"min_g": _finite(rng[i, 0]), "max_g": _finite(rng[i, 1]),
                             "both_sides_0.3g": bool(self.covered[i])}
                         for i, a in enumerate(AXES)},
            "suffices": {"check_accelerometer": self.acc_enough,
                         "check_gyroscope": self.gyro_enough if self.gyro else None,
                         "refresh_gyroscope_bias": self.gyro_enough if self.gyro else None,
                         "refresh_accelerometer_axes": [a for a, c in zip(AXES, self.covered)
                                                        if c]},
            "notes": list(self.notes)}

    def lines(self) -> list[str]:
        m = self.moments
        out = [f"still moments   {m.count}, {self.still_s:.1f} s in all, {m.orientations} "
               f"orientation(s) 15 deg apart, over {self.duration:.1f} s at {self.rate:.4g} Hz",
               f"detector        window {m.window}, shortest {m.min_len} samples, k {m.k:g} on "
               f"{m.level_from}" + (f": about {self.noise_mg:.3g} mg per sample "
                                    f"({self.noise_density:.2g} mg/sqrt(Hz))"
                                    if np.isfinite(self.noise_mg) else "")]
        out += [f"  refused       {v} run(s): {k}" for k, v in m.rejected.items()]
        for i, (a, b) in enumerate(m.times):
            u = m.cal_mean[i] / self.g
            r = None if self.rate_at_rest is None else np.degrees(self.rate_at_rest[i])
            rate = "" if r is None else (
                f", rate at rest ({r[0]:+.3f}, {r[1]:+.3f}, {r[2]:+.3f}) deg/s")
            out.append(f"  {a:9.2f}-{b:<9.2f} s {b - a:6.1f} s  mean ({u[0]:+.3f}, {u[1]:+.3f}, "
                       f"{u[2]:+.3f}) g{rate}")
        rng = self.axis_range
        cov = ", ".join(f"{a} {rng[i, 0]:+.2f} to {rng[i, 1]:+.2f} g"
                        + (" (covered)" if self.covered[i] else "") for i, a in enumerate(AXES))
        out.append(f"coverage        {cov if m.count else 'none'}; refresh updates an axis' "
                   f"bias and scale with moments at {COVERAGE_G:g} g on both sides and "
                   f"{MIN_ACC_MOMENTS} moments or more")
        acc = ("yes" if self.acc_enough else
               f"no: {m.count} moment(s) in {m.orientations} orientation(s), "
               f"{MIN_ACC_MOMENTS} in {MIN_ACC_ORIENTATIONS} needed")
        out.append(f"check accel.    {acc}")
        if self.gyro:
            gyro = ("yes" if self.gyro_enough else
                    f"no: {self.still_s:.1f} s still, {MIN_GYRO_STILL_S:g} s needed")
            out.append(f"check gyro      {gyro}; refresh would "
                       f"{'update' if self.gyro_enough else 'keep'} the gyroscope's bias")
        axes = [a for a, c in zip(AXES, self.covered) if c]
        out.append("refresh accel.  " + (f"bias and scale of {', '.join(axes)}" if axes
                                         else "nothing (no axis covered)"))
        if self.notes:
            out.append("notes:")
            out += [f"  - {n}" for n in self.notes]
        return out


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def survey(session: Session) -> Survey:
    """The still moments of ``session`` read in its own units, the noise learned from it."""
    if session.acc_unit == "counts":
        raise ImucalError("the accelerometer is in raw counts: without a calibration |g| and "
                          "the orientations are unknown; give the unit (--acc-unit g or m/s^2) "
                          "if the values are in one, or a calibration (imucal check "
                          "CALIB.json RECORDING)", source=session.source,
                          field="accelerometer unit")
    g = 1.0 if session.acc_unit == "g" else STANDARD_GRAVITY
    notes = ["no calibration: the signals as recorded, the noise learned from the recording"]
    gyro = session.has_gyro and session.gyro_unit == "rad/s"
    if session.has_gyro and not gyro:
        notes.append("the gyroscope is in raw counts: its moments are not judged (no rate "
                     "limit, no bias); give --gyro-unit")
    if session.acc_rate < SLOW_HZ:  # PX4's sensor_accel topics are logged at 1 Hz
        notes.append(f"the accelerometer is logged at {session.acc_rate:.3g} Hz, too slow to "
                     "see a moment's noise: 'imucal inspect' lists the file's streams, --acc "
                     "and --gyro take a faster one")
    t = np.asarray(session.t_acc)
    m = find_moments(session.acc, session.acc, t, None, None, g, None, session.acc_rate)
    offset = np.zeros(3)
    if gyro and m.count:
        g0 = np.searchsorted(session.t_gyro, m.times[:, 0])
        g1 = np.searchsorted(session.t_gyro, m.times[:, 1], side="right")
        means = np.array([np.mean(session.gyro[a:b], axis=0) for a, b in zip(g0, g1) if b > a])
        offset = np.median(means, axis=0) if len(means) else offset
        less = ModelRows(session.gyro, SensorModel(T=np.eye(3), K=np.ones(3), b=offset))
        m = find_moments(session.acc, session.acc, t, less, session.t_gyro, g, None,
                         session.acc_rate)
        notes.append(f"the gyroscope's 3 deg/s rule on the rate less the moments' median, "
                     f"({', '.join(f'{x:+.3f}' for x in np.degrees(offset))}) deg/s")
    # M1 of white noise is 3 sigma^4 (three axes of variance sigma^2, squared).
    sigma_mg = (m.level / 3.0) ** 0.25 / g * 1e3 if np.isfinite(m.level) else float("nan")
    s = Survey(moments=m, g=g, unit=session.acc_unit, rate=session.acc_rate,
               duration=session.duration, gyro=gyro, noise_mg=sigma_mg, notes=tuple(notes),
               gyro_offset=offset)
    if not s.noise_plausible:
        s = dataclasses.replace(s, notes=s.notes + (
            f"the quietest windows' noise, {s.noise_density:.2g} mg/sqrt(Hz), is above any "
            f"MEMS accelerometer's at rest ({NOISE_CEILING_MG_RT_HZ:g} and less): the "
            "recording may never rest (motors running throughout), and its moments be "
            "vibration; a calibration with the sensor's noise (imucal check CALIB.json "
            "RECORDING) tells them apart",))
    return s
