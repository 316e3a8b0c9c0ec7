"""The still moments of real recordings of use that come without a calibration of their device
(method.md §10; imucal.inuse.survey, ``imucal check --moments-only``): the two flight logs and
x-io's hand-held Fusion recording. With no calibration, what can be judged is where the
moments are, against what each log says of itself (its land detector, barometer, estimator)
and what the signals show independently of the detector.

Neither flight log holds a flight the IMU felt: PX4's sample is 6.5 s of a VTOL armed on the
ground, whose land detector reports 1.15 s "airborne" that no sensor confirms; ArduPilot's is
0.97 s of a plane armed on the ground. The rule "no moment in flight" is tested on synthetic
flights (tests/inuse/test_flight.py, and the vibration note below)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import imucal
from imucal.inuse.check import CANNOT_TELL, DRIFTED, HOLDS, Stored, check
from imucal.inuse.survey import NOISE_CEILING_MG_RT_HZ, survey
from imucal.models import SensorModel
from imucal.stages.apply import Calibration, SegmentModels

IDENT = SensorModel(T=np.eye(3), K=np.ones(3), b=np.zeros(3))


def identity(unit: str, g: float) -> Calibration:
    return Calibration(segments=(SegmentModels(0.0, 0.0, IDENT, IDENT),), acc_unit_raw=unit,
                       acc_unit=unit, g=g, gyro_unit_raw="rad/s")


def _blocks(x: np.ndarray, t: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    k = len(x) // n
    return x[:k * n].reshape(k, n, -1), t[:k * n].reshape(k, n).mean(axis=1)


def test_px4_log_rests_throughout_and_its_one_moment_spans_the_land_detectors_flight(
        shared_data):
    """PX4's sample (sensor_combined, PX4's selected IMU at 205 Hz): the land detector says
    airborne from 22.67 to 23.82 s, but the IMU felt no take-off: the specific force's norm
    stays within 0.01 m/s^2 of its rest value (a climb of 0.5 m in that time needs 3 m/s^2),
    the vibration's RMS in the "flight" lies within the range before it (no motor vibration:
    thrust at most 8 %), the barometer moves by 3 cm. The one moment found covers it; it
    starts before the reported take-off. Its rate at rest about x, 0.255 deg/s, is the bias
    PX4's own estimator holds for that IMU (0.255-0.261 deg/s)."""
    from pyulog import ULog

    path = shared_data / "px4_ulog" / "sample_log_small.ulg"
    s = imucal.load_session(path, select={"acc": "sensor_combined", "gyro": "sensor_combined"})
    log = ULog(str(path), ["vehicle_land_detected", "vehicle_air_data",
                           "estimator_sensor_bias", "sensor_selection",
                           "vehicle_magnetometer"])
    d = {x.name: x.data for x in log.data_list}
    messages = [m.message for m in log.logged_messages]
    assert "[commander] Takeoff detected" in messages
    assert "[commander] Landing detected" in messages
    # the log's own flight: the land detector's "landed" false (same clock as imucal's)
    ld = d["vehicle_land_detected"]
    t_ld, landed = ld["timestamp"] / 1e6, ld["landed"].astype(bool)
    up = np.flatnonzero(~landed)
    takeoff, landing = t_ld[up[0]], t_ld[up[-1] + 1]
    assert 1.0 < landing - takeoff < 1.3 and takeoff - s.t_acc[0] < 3.0  # 1.15 s; 2.35 s
    # what the sensors say of it, without the detector: 0.5 s blocks of the accelerometer
    blk, tb = _blocks(np.asarray(s.acc), s.t_acc, int(0.5 * s.acc_rate))
    rms = np.sqrt(((blk - blk.mean(axis=1, keepdims=True)) ** 2).sum(axis=2).mean(axis=1))
    norm = np.linalg.norm(blk.mean(axis=1), axis=1)
    air, before = (tb >= takeoff) & (tb < landing), tb < takeoff
    assert air.sum() >= 2 and before.sum() >= 3
    assert np.abs(norm - np.median(norm[before])).max() < 0.015  # m/s^2; measured 0.0095
    assert rms[air].max() < 1.2 * rms[before].max()  # measured 0.061 against 0.061
    baro = d["vehicle_air_data"]
    t_b, alt = baro["timestamp"] / 1e6, baro["baro_alt_meter"]
    climb = alt[(t_b >= takeoff) & (t_b < landing)].mean() - alt[t_b < takeoff].mean()
    assert abs(climb) < 0.2  # m; measured -0.03
    # the moments: one, from before the reported take-off to past the landing
    v = survey(s)
    m = v.moments
    assert m.count == 1 and m.orientations == 1
    (a, b), = m.times
    assert a < takeoff and b > landing
    assert (b - a) / s.duration > 0.85  # 5.84 of 6.50 s: the log's first 0.16 s is a gap
    assert v.noise_plausible and v.noise_mg < 4.0  # measured 2.76 mg (0.19 mg/sqrt(Hz))
    assert v.gyro_enough and not v.acc_enough and v.exit_code == 2  # one orientation
    slow = survey(imucal.load_session(path))  # the first IMU's own topics: 1 Hz, 6 samples
    assert slow.moments.count == 0 and any("'imucal inspect'" in n for n in slow.notes)
    # the rate at rest against the EKF's bias for the same IMU (x: converged; y, z are not:
    # y still falls 0.004 deg/s a second, z reads 3.2-4.3 deg/s while the magnetometer's
    # heading holds within 0.2 deg over the moment)
    eb = d["estimator_sensor_bias"]
    assert eb["gyro_device_id"][0] == d["sensor_selection"]["gyro_device_id"][0]
    t_e = eb["timestamp"] / 1e6
    inside = (t_e >= a) & (t_e <= b)
    ekf_x = np.degrees(eb["gyro_bias[0]"][inside])
    rate = np.degrees(v.rate_at_rest[0])
    assert abs(rate[0] - ekf_x.mean()) < 0.01  # deg/s; measured 0.255 against 0.258
    assert abs(rate[2]) < 0.1 and np.degrees(eb["gyro_bias[2]"][inside]).min() > 3.0
    mag = d["vehicle_magnetometer"]
    t_m = mag["timestamp"] / 1e6
    heading = np.degrees(np.arctan2(mag["magnetometer_ga[1]"], mag["magnetometer_ga[0]"]))
    first, last = (t_m >= a) & (t_m < a + 1.0), (t_m > b - 1.0) & (t_m <= b)
    assert abs(heading[last].mean() - heading[first].mean()) < 0.5  # deg; measured 0.16


def test_ardupilot_log_holds_no_rest_of_3_s_and_no_moment(shared_data):
    """ArduPilot's sample: 0.97 s of IMU, armed on the ground (its STAT says not flying, the
    throttle is at zero, the barometer within 0.1 m). Shorter than one moment (2 s), let alone
    the 3 s a rest before take-off would need: no moment, and check cannot tell."""
    from pymavlink import mavutil

    path = shared_data / "ardupilot_dataflash" / "test.BIN"
    s = imucal.load_session(path)
    log = mavutil.mavlink_connection(str(path))
    rows: dict[str, list] = {"STAT": [], "CTUN": [], "BARO": []}
    try:
        while (msg := log.recv_match(type=list(rows))) is not None:
            rows[msg.get_type()].append(msg.to_dict())
    finally:
        log.close()  # not left to the garbage collector: it would warn inside another test
    assert rows["STAT"] and all(r["isFlying"] == 0 and r["Armed"] == 1 for r in rows["STAT"])
    assert all(r["ThrOut"] == 0 for r in rows["CTUN"])
    assert max(abs(r["Alt"]) for r in rows["BARO"]) < 0.2  # m; measured 0.13
    assert s.duration < 3.0  # 0.97 s at 50 Hz: no rest of 3 s can be in it
    v = survey(s)
    assert v.moments.count == 0 and v.exit_code == 2
    c = check(identity("m/s^2", 9.80665), Stored(), s)
    assert c.level == CANNOT_TELL and "too few still moments (0" in c.reason


@pytest.fixture(scope="module")
def xio(shared_data):
    return imucal.load_session(shared_data / "xio_fusion" / "sensor_data.csv")


def test_xio_moments_are_its_rests_on_the_table(xio):
    """x-io's Fusion example: 135 s, hand-held between rests on a table. The moments are the
    six rests on the table (43.7 s, the sensor's own noise: 2.3 mg, 0.1 deg/s), all in one
    orientation (z up, never upside down): enough for the gyroscope's bias, not for the
    accelerometer. The hand's holds on +-x and +-y (0.8-0.9 g; a hand's tremor of 5-10 mg and
    0.3-1.5 deg/s) are not still moments at k = 9: a hand is not at rest."""
    v = survey(xio)
    m = v.moments
    assert m.count == 6 and 40.0 < v.still_s < 48.0  # measured 43.7 s
    assert m.orientations == 1 and v.noise_plausible
    assert 1.8 < v.noise_mg < 3.0  # measured 2.33 mg per sample (0.23 mg/sqrt(Hz))
    acc, gyro = np.asarray(xio.acc), np.asarray(xio.gyro)
    for a, b in m.blocks:
        assert acc[a:b].std(axis=0).max() < 4e-3  # g: the table's rest, not a hand's hold
        assert np.degrees(gyro[a:b].std(axis=0)).max() < 0.2
    rng = v.axis_range
    assert rng[2, 0] > 0.99 and np.abs(rng[:2]).max() < 0.03  # z up in every moment
    assert not v.covered.any() and not v.acc_enough and v.gyro_enough and v.exit_code == 2
    # the rests the signals show (1 s blocks: every axis under 4 mg and 0.15 deg/s): the
    # moments hold nearly all of them (what they miss is the detector's half windows at the
    # ends), and one second besides (the settling after a spin at 75.6 s)
    blk, tb = _blocks(acc, xio.t_acc, 100)
    gb, _ = _blocks(gyro, xio.t_gyro, 100)
    rest = (blk.std(axis=1).max(axis=1) < 4e-3) & (np.degrees(gb.std(axis=1)).max(axis=1)
                                                    < 0.15)
    held = np.array([((m.times[:, 0] <= t) & (m.times[:, 1] >= t)).any() for t in tb])
    assert rest.sum() >= 40 and (held & rest).sum() / rest.sum() > 0.9  # measured 43 of 45
    assert (held & ~rest).sum() <= 1
    # the gyroscope's bias at rest repeats: the moments before 70 s and after agree
    early, late = m.times[:, 1] < 70.0, m.times[:, 0] > 70.0
    assert early.sum() >= 2 and late.sum() >= 3
    w = 1.0 / m.rate_se**2
    pooled = [np.degrees((w[k] * m.rate[k]).sum(axis=0) / w[k].sum(axis=0))
              for k in (early, late)]
    assert np.abs(pooled[0] - pooled[1]).max() < 0.03  # deg/s; measured 0.022 (y)


def test_xio_with_a_synthetic_sessions_calibration(xio):
    """A calibration in xio's units (g, rad/s) made for a synthetic desk session, not this
    device's: check's verdict (drifted) says nothing of the device; what the recording can
    determine is. Its gyroscope bias, 2.7 deg/s from xio's about z, pushes one of the six rests
    past the 3 deg/s rule; refresh updates the gyroscope's bias from the other five, keeps every
    accelerometer parameter as stored (too few moments, one orientation), and re-checked with
    the refreshed bias all six rests come back and the gyroscope holds. The accelerometer's
    23 mg still-norm error is the synthetic calibration's scales and biases, not xio's."""
    from imucal.inuse.everyday import make_everyday
    from imucal.inuse.refresh import refresh

    _, truth = make_everyday("desk", minutes=2, seed=1)  # imucal synth --activity desk
    seg = SegmentModels(0.0, 0.0, truth.stored_acc, truth.stored_gyro)
    cal = Calibration(segments=(seg,), acc_unit_raw="g", acc_unit="g", g=1.0,
                      gyro_unit_raw="rad/s")
    stored = Stored(acc_noise_density=0.003 / 10.0)  # the synthetic sensor's, as synth stores
    c = check(cal, stored, xio)
    assert c.level == DRIFTED and c.moments.count == 5
    assert c.moments.rejected == {"mean rate above 3 deg/s": 1}
    assert c.parts[0].level == DRIFTED and c.parts[0].value > 15  # mg; measured 23.0
    r = refresh(cal, stored, xio)
    assert {(e.sensor, e.parameter) for e in r.changed} == {
        ("gyroscope", "b_x"), ("gyroscope", "b_y"), ("gyroscope", "b_z")}
    assert np.array_equal(r.acc.b, truth.stored_acc.b) and np.array_equal(r.acc.K,
                                                                          truth.stored_acc.K)
    assert "accelerometer biases and scales: 5 still moments, 6 needed" in r.kept
    new = Calibration(segments=(dataclasses.replace(seg, gyro=r.gyro),), acc_unit_raw="g",
                      acc_unit="g", g=1.0, gyro_unit_raw="rad/s")
    again = check(new, stored, xio)
    assert again.moments.count == 6
    gyro = {p.sensor: p for p in again.parts}["gyroscope"]
    assert gyro.level == HOLDS and gyro.value < 0.05  # deg/s; measured 0.006
    assert again.moments.rejected == {}


def test_a_flight_that_never_rests_is_doubted_without_a_calibration():
    """The noise learned from a recording is the sensor's only where it rests: a synthetic
    flight cut between its rests (motors idling, flying, idling) teaches the detector the
    idling's vibration, whose moments are found; the survey says the level is no sensor's at
    rest and exits 2. The whole flight, rests included, learns the sensor's noise: its moments
    are its rests and no note."""
    from imucal.inuse.everyday import make_everyday

    session, truth = make_everyday("flight", minutes=6, seed=1)
    model = truth.stored_acc  # a calibration's model, so that the norm rule holds

    def calibrated(s):
        return dataclasses.replace(s, acc=model.apply(s.acc), gyro=truth.stored_gyro.apply(
            s.gyro))

    whole = survey(calibrated(session))
    assert whole.noise_plausible and whole.moments.count == len(truth.still)
    for a, b in whole.moments.times:
        assert ((truth.still[:, 0] <= a) & (truth.still[:, 1] >= b)).any()
    a0, b0 = truth.still[0, 1], truth.still[1, 0]
    k = (session.t_acc >= a0) & (session.t_acc < b0)
    cut = calibrated(dataclasses.replace(session, acc=session.acc[k], t_acc=session.t_acc[k],
                                         gyro=session.gyro[k], t_gyro=session.t_gyro[k]))
    v = survey(cut)
    assert v.moments.count >= 1  # the idling before take-off and after landing
    assert v.noise_density > NOISE_CEILING_MG_RT_HZ and not v.noise_plausible  # 2.3 (the
    # sensor's own: 0.27 mg/sqrt(Hz); seeds 0-3 cut: 2.3-3.1)
    assert v.exit_code == 2 and any("may never rest" in n for n in v.notes)


def test_a_gyroscope_biased_beyond_the_rate_rule_keeps_its_moments():
    """Without a calibration the raw bias is in the rate: the 3 deg/s rule is applied to the
    rate less the moments' median, so a gyroscope 5 deg/s off (as MEMS parts leave the
    factory) keeps its moments, and each moment's rate at rest is the bias."""
    from imucal.inuse.everyday import make_everyday

    session, truth = make_everyday("walk", minutes=5, seed=2)
    acc = truth.stored_acc.apply(session.acc)
    bias = np.radians([5.0, -4.0, 3.0])
    s = dataclasses.replace(session, acc=acc, gyro=truth.stored_gyro.apply(session.gyro) + bias)
    v = survey(s)
    assert v.moments.count >= 5 and v.moments.rejected == {}
    np.testing.assert_allclose(v.gyro_offset, bias, atol=np.radians(0.05))
    np.testing.assert_allclose(v.rate_at_rest, np.broadcast_to(bias, v.rate_at_rest.shape),
                               atol=np.radians(0.1))
    plain = check(identity("g", 1.0), Stored(), s).moments  # the rule on the raw rate
    assert plain.count == 0 and plain.rejected["mean rate above 3 deg/s"] == v.moments.count


def test_a_coarse_quantiser_at_rest_still_teaches_a_noise_level():
    """An 8-bit accelerometer at +-2 g (16 mg a step, 1 mg of noise) lies flat on most
    windows of a rest: M1 there is rounding error, and the quietest 1 % of windows would make
    the level about 0 and nothing still. Left out as §1 leaves them, the level comes from the
    windows where a step flips: the rests are found (27 of 30), and nothing else."""
    from imucal.inuse.everyday import make_everyday

    session, truth = make_everyday("desk", minutes=5, seed=4, acc_noise=0.001)
    step = 1.0 / 64
    acc = np.round(truth.stored_acc.apply(session.acc) / step) * step
    s = dataclasses.replace(session, acc=acc, gyro=truth.stored_gyro.apply(session.gyro))
    v = survey(s)
    m = v.moments
    assert m.count >= 0.8 * len(truth.still) and v.noise_mg > 1.0  # measured 27 of 30
    for a, b in m.times:
        assert ((truth.still[:, 0] - 0.35 <= a) & (truth.still[:, 1] + 0.35 >= b)).any()
        assert not np.any((truth.taps >= a - 0.02) & (truth.taps < b))
