"""Several triads and a bias in temperature in the exports (issue 24 item 5): each target's own
equation, written here from its source (not imported from imucal), applied to raw samples at
chosen temperatures must give imucal's own output (``BiasPolynomial.calibrated``, each triad's
``Calibration.apply``), up to exactly what the export says it drops.

- px4:       a = (a_m - thermal - CAL_ACCn_xOFF) * CAL_ACCn_xSCALE, w = w_m - thermal -
             CAL_GYROn_xOFF; thermal = X0 + X1 dT + X2 dT^2 + X3 dT^3, dT = clip(T, TMIN, TMAX)
             - TREF (TemperatureCompensation::calc_thermal_offsets_3D, Accelerometer::Correct).
- ardupilot: v -= P(clip(T) - 35); v += P(clip(CALTEMP) - 35); v -= OFFS; v *= SCAL, P(x) =
             (C1 + (C2 + C3 x) x) x * 1e-6 (TCal::correct_sensor, _rotate_and_correct_accel).
- c:         the generated header compiled with gcc: the _at functions and each triad's.
- json/yaml: the models as the documents' own "model" texts state them.
"""

from __future__ import annotations

import json
import re
import subprocess

import numpy as np
import pytest
from export_files import export_all

import imucal
from imucal.io.exports import export
from imucal.pipeline import calibrate_temperature, calibrate_triads
from imucal.synth import SecondTriad, TemperatureProfile, make_session
from tests.io.test_exports import _compile, needs_gcc, read_yaml

G_N = 9.80665


@pytest.fixture(scope="module")
def device(tmp_path_factory):
    """Two IMUs (a2 with its gyroscope g2, turned 3 deg) and a 15-45 deg C ramp, in g."""
    session, truth = make_session(poses=20, seed=4, second_acc=SecondTriad(gyro=True),
                                  temperature=TemperatureProfile())
    result = calibrate_triads(calibrate_temperature(imucal.calibrate(session)), "all", True)
    assert result.temperature and result.triads[0].result.temperature
    path = tmp_path_factory.mktemp("device") / "calib.json"
    imucal.save_calibration(result, path)
    return path, session, result, truth


def _fits(result) -> dict:
    return {f.sensor: f for f in result.temperature}


def _gyro_at(result, fit, raw, temp):
    """imucal's gyroscope in temperature: T_g K_g (raw - b(T)) (M4 with M16's bias)."""
    return (raw - fit.bias_at(temp)) @ result.segments[0].gyro.model.matrix.T


def _px4(text: str) -> dict[str, float]:
    out = {}
    for line in text.splitlines():
        if line.startswith("#") or not line.strip():
            continue
        vehicle, comp, name, value, ptype = line.split("\t")
        assert (vehicle, comp) == ("1", "1") and ptype in ("6", "9")
        out[name] = float(value)
    return out


def _ardupilot(text: str) -> dict[str, float]:
    return {n: float(v) for n, v in (line.split(",") for line in text.splitlines()
                                     if line.strip() and not line.startswith("#"))}


def _px4_thermal(p: dict, kind: str, n: int, temp: np.ndarray) -> np.ndarray:
    if p.get(f"TC_{kind}_ENABLE") != 1 or f"TC_{kind}{n}_TREF" not in p:
        return np.zeros((len(temp), 3))
    lo, hi, ref = (p[f"TC_{kind}{n}_{k}"] for k in ("TMIN", "TMAX", "TREF"))
    dt = np.clip(temp, lo, hi) - ref
    x = {j: np.array([p[f"TC_{kind}{n}_X{j}_{i}"] for i in range(3)]) for j in range(4)}
    return x[0] + np.outer(dt, x[1]) + np.outer(dt**2, x[2]) + np.outer(dt**3, x[3])


def _ap_thermal(p: dict, k: int, tag: str, temp: np.ndarray) -> np.ndarray:
    if p.get(f"INS_TCAL{k}_ENABLE") != 1:
        return np.zeros((len(temp), 3))
    lo, hi = p[f"INS_TCAL{k}_TMIN"], p[f"INS_TCAL{k}_TMAX"]
    c = [np.array([p[f"INS_TCAL{k}_{tag}{m}_{a}"] for a in "XYZ"]) for m in (1, 2, 3)]

    def poly(x):
        x = np.asarray(x, float)[:, None]
        return (c[0] + (c[1] + c[2] * x) * x) * x * 1e-6

    cal_t = np.clip(p[f"INS_{tag}{k}_CALTEMP"], lo, hi)
    return poly(np.clip(temp, lo, hi) - 35.0) - poly(np.array([cal_t - 35.0]))


def _names(k: int) -> tuple[str, str, str]:
    return (("INS_ACCOFFS", "INS_ACCSCAL", "INS_GYROFFS") if k == 1 else
            (f"INS_ACC{k}OFFS", f"INS_ACC{k}SCAL", f"INS_GYR{k}OFFS"))


def _autopilot(fmt: str, p: dict, n: int, acc: np.ndarray, gyro: np.ndarray,
               temp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The autopilot's own correction of instance n (from 0), m/s^2 and rad/s."""
    if fmt == "px4":
        off, scale, goff = ([p[f"CAL_{s}{n}_{a}{k}"] for a in "XYZ"] for s, k in
                            (("ACC", "OFF"), ("ACC", "SCALE"), ("GYRO", "OFF")))
        a = (acc - _px4_thermal(p, "A", n, temp) - off) * scale
        return a, gyro - _px4_thermal(p, "G", n, temp) - goff
    off, scale, goff = ([p[f"{name}_{a}"] for a in "XYZ"] for name in _names(n + 1))
    a = (acc - _ap_thermal(p, n + 1, "ACC", temp) - off) * scale
    return a, gyro - _ap_thermal(p, n + 1, "GYR", temp) - goff


def _stated(text: str, head: str) -> list[str]:
    """The comment lines under one instance's heading."""
    lines = text.splitlines()
    i = lines.index(f"# {head}")
    out = []
    for line in lines[i + 1:]:
        if not line.startswith("#   "):
            break
        out.append(line[4:])
    return out


@pytest.mark.parametrize("fmt", ["px4", "ardupilot"])
def test_autopilot_instances_and_thermal_round_trip(fmt, device, tmp_path):
    path, session, result, truth = device
    res = export(path, fmt, tmp_path / "params")
    text = (tmp_path / "params").read_text()
    p = _px4(text) if fmt == "px4" else _ardupilot(text)
    # Temperatures from below the span to above it: the clipping is exercised too.
    tri = result.triads[0]
    a2, g2 = (s.values for s in session.others[:2])
    cases = [(0, session.acc, session.gyro, result), (1, a2, g2, tri.result)]
    for n, acc, gyro, own in cases:
        temp = np.linspace(5.0, 55.0, len(acc))
        fits = _fits(own)
        got_a, got_g = _autopilot(fmt, p, n, acc * G_N, gyro, temp)
        # What the export keeps: the bias in temperature and the diagonal scale, exactly.
        fa = fits["accelerometer"]
        diag = (acc - fa.bias_at(temp)) * fa.model.K * G_N
        assert np.allclose(got_a, diag, rtol=1e-12, atol=1e-12)
        assert np.allclose(got_g, gyro - fits["gyroscope"].bias_at(temp), rtol=0, atol=1e-14)
        # What it drops, the misalignment, within the stated worst case on still samples.
        head = f"instance {n}" if fmt == "px4" else f"IMU {n + 1}"
        name = "the calibrated accelerometer (the reference)" if n == 0 else "acc a2"
        said = _stated(text, f"{head}: {name}")
        worst = float(re.search(r"([\d.e+-]+) mg at most", said[0]).group(1))
        t = session.t_acc if n == 0 else session.others[0].t
        still = np.zeros(len(t), bool)
        for lo, hi in truth.pose_times:
            still |= (t > lo + 0.3) & (t < hi - 0.3)
        full = fa.calibrated(acc, temp) * G_N
        err = np.linalg.norm(got_a[still] - full[still], axis=1) / G_N * 1000.0
        assert 1.0 < err.max() <= worst * 1.02 + 0.05
    # The rotation neither target holds: its angle and size said, for instance 1 only.
    angle = tri.agreement.angle_deg
    line = next(x for x in _stated(text, f"{'instance 1' if fmt == 'px4' else 'IMU 2'}: acc a2")
                if "rotation to the reference" in x)
    assert f"{angle:.3g} deg" in line
    assert f"up to {2 * np.sin(np.radians(angle) / 2) * 1000:.3g} mg" in line
    assert any("rotation to the reference" in x for x in res.notes)


def test_ardupilot_polynomial_is_stored_about_35_degrees(device, tmp_path):
    """The same bias, whatever CALTEMP: the offsets move with it (ArduPilot's reference is a
    fixed 35 deg C, the calibration temperature only shifts where the offsets hold)."""
    path, _, result, _ = device
    export(path, "ardupilot", tmp_path / "p")
    p = _ardupilot((tmp_path / "p").read_text())
    fit = _fits(result)["gyroscope"]
    assert fit.order == 2  # a curve: its slope at 35 deg C is not its slope at t0
    assert p["INS_GYR1_CALTEMP"] == pytest.approx(fit.t0)
    assert p["INS_TCAL1_TMIN"] == fit.span[0] and p["INS_TCAL1_TMAX"] == fit.span[1]
    # d b / dT at 35 deg C and half the second derivative, in rad/s per deg C^j, times 1e6
    c = fit.coefs
    assert np.allclose([p[f"INS_TCAL1_GYR1_{a}"] for a in "XYZ"],
                       (c[1] + 2 * c[2] * (35.0 - fit.t0)) * 1e6, rtol=1e-12)
    assert np.allclose([p[f"INS_TCAL1_GYR2_{a}"] for a in "XYZ"], c[2] * 1e6, rtol=1e-12)
    assert [p[f"INS_TCAL1_GYR3_{a}"] for a in "XYZ"] == [0.0, 0.0, 0.0]


def test_a_scale_slope_is_said_with_its_size(device, tmp_path):
    """A scale slope neither autopilot holds: the stated mg is what dropping it costs at the
    span's ends (the misalignment set to zero so that nothing else differs)."""
    path, session, _, truth = device
    doc = json.loads(path.read_text())
    acc = doc["temperature"]["accelerometer"]
    acc["scale_slope_per_degC"] = [3e-4, -2e-4, 1e-4]
    acc["T"] = np.eye(3).tolist()
    edited = tmp_path / "slope.json"
    edited.write_text(json.dumps(doc))
    fit = imucal.io.exports.read_export_input(edited).extras.temperature["accelerometer"]
    for fmt in ("px4", "ardupilot"):
        export(edited, fmt, tmp_path / fmt)
        text = (tmp_path / fmt).read_text()
        worst = float(re.search(r"scales' slope in temperature \([^)]*\) is not held \([^)]*\): "
                                r"up to ([\d.e+-]+) mg", text).group(1))
        p = _px4(text) if fmt == "px4" else _ardupilot(text)
        still = np.zeros(len(session.t_acc), bool)
        for lo, hi in truth.pose_times:
            still |= (session.t_acc > lo + 0.3) & (session.t_acc < hi - 0.3)
        for end in fit.span:
            temp = np.full(still.sum(), end)
            got, _ = _autopilot(fmt, p, 0, session.acc[still] * G_N, session.gyro[still], temp)
            err = np.linalg.norm(got - fit.calibrated(session.acc[still], temp) * G_N,
                                 axis=1) / G_N * 1000
            assert 0.5 * worst < err.max() <= worst * 1.01


_C_MAIN = r"""
#include <stdio.h>
#include "export.h"
int main(void) {
    char which[8]; double t, temp, x, y, z;
    while (scanf(" %7s %lf %lf %lf %lf %lf", which, &t, &temp, &x, &y, &z) == 6) {
        imucal_real raw[3] = {(imucal_real)x, (imucal_real)y, (imucal_real)z}, out[3];
        switch (which[0]) {
        case 'a': imucal_calibrate_accelerometer_at(temp, raw, out); break;
        case 'g': imucal_calibrate_gyroscope_at(temp, raw, out); break;
        case 'A': imucal_triad1_calibrate_accelerometer_at(temp, raw, out); break;
        case 'G': imucal_triad1_calibrate_gyroscope_at(temp, raw, out); break;
        case 'r': imucal_triad1_accelerometer_in_reference(t, raw, out); break;
        default: imucal_triad1_gyroscope_in_reference(t, raw, out); break;
        }
        printf("%.17g %.17g %.17g\n", (double)out[0], (double)out[1], (double)out[2]);
    }
    return IMUCAL_HAS_TEMPERATURE == 1 && IMUCAL_TRIADS == 1 ? 0 : 1;
}
"""


@needs_gcc
def test_c_header_calibrates_in_temperature_and_each_triad(device, tmp_path):
    path, session, result, _ = device
    export(path, "c", tmp_path / "export.h")
    exe = _compile(tmp_path, {"main.c": _C_MAIN})
    tri = result.triads[0]
    a2, g2 = session.others[:2]
    idx = np.arange(0, len(a2.t), 41)
    temp = np.linspace(5.0, 55.0, len(idx))
    rows, want = [], []
    own, ref = _fits(tri.result), _fits(result)
    R = tri.agreement.rotation.R
    cal2 = tri.result.calibration
    for tag, raw, t, expect in (
            ("a", session.acc[idx], session.t_acc[idx], ref["accelerometer"].calibrated(
                session.acc[idx], temp)),
            ("g", session.gyro[idx], session.t_gyro[idx],
             _gyro_at(result, ref["gyroscope"], session.gyro[idx], temp)),
            ("A", a2.values[idx], a2.t[idx], own["accelerometer"].calibrated(a2.values[idx],
                                                                             temp)),
            ("G", g2.values[idx], g2.t[idx],
             _gyro_at(tri.result, own["gyroscope"], g2.values[idx], temp)),
            ("r", a2.values[idx], a2.t[idx], cal2.segments[0].acc.apply(a2.values[idx]) @ R.T),
            ("q", g2.values[idx], g2.t[idx], cal2.segments[0].gyro.apply(g2.values[idx]) @ R.T)):
        rows += [" ".join([tag, *(repr(float(v)) for v in (t[i], temp[i], *raw[i]))])
                 for i in range(len(idx))]
        want.append(expect)
    proc = subprocess.run([str(exe)], input="\n".join(rows), capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 0
    got = np.array(proc.stdout.split(), dtype=float).reshape(-1, 3)
    want = np.vstack(want)
    assert np.max(np.abs(got - want)) < 1e-12 * np.abs(want).max()


@pytest.mark.parametrize("fmt", ["json", "yaml"])
def test_plain_exports_carry_triads_and_temperature(fmt, device, tmp_path):
    path, session, result, _ = device
    export(path, fmt, tmp_path / f"e.{fmt}")
    text = (tmp_path / f"e.{fmt}").read_text()
    doc = json.loads(text) if fmt == "json" else read_yaml(text)
    a2 = session.others[0]
    temp = np.linspace(5.0, 55.0, len(a2.t))
    tri = result.triads[0]
    for sec, fit, raw in ((doc["temperature"], _fits(result)["accelerometer"], session.acc),
                          (doc["triads"]["triads"][0]["temperature"],
                           _fits(tri.result)["accelerometer"], a2.values)):
        m = sec["accelerometer"]
        tt = temp[: len(raw)] if len(temp) >= len(raw) else np.linspace(5, 55, len(raw))
        x = np.clip(tt, m["t_min"], m["t_max"]) - m["t0"]  # the document's own rule
        b = np.array(m["b0"]) + sum(np.outer(x**j, c) for j, c in enumerate(m["c"]))
        got = ((raw - b) * (1 + np.outer(x, m["k"]))) @ np.array(m["A"]).T
        assert np.allclose(got, fit.calibrated(raw, tt), rtol=0, atol=1e-13)
    entry = doc["triads"]["triads"][0]
    assert entry["accelerometer"] == "acc a2" and entry["instance"] == 1
    assert np.allclose(entry["rotation_to_reference"], tri.agreement.rotation.R, atol=1e-15)
    (piece,) = entry["pieces"]
    want = tri.result.calibration.segments[0].acc.apply(a2.values)
    got = (a2.values - np.array(piece["accelerometer"]["b"])) @ np.array(
        piece["accelerometer"]["A"]).T
    assert np.allclose(got, want, rtol=0, atol=1e-13)


def test_without_triads_or_temperature_the_exports_are_unchanged(device, tmp_path):
    """A file without the sections exports as before: the formats that do not carry them are
    the same bytes with and without; the others hold one instance and no thermal words."""
    path, *_ = device
    doc = json.loads(path.read_text())
    (tmp_path / "p").mkdir()
    plain = tmp_path / "p" / path.name  # the same name: the files' comments name it
    plain.write_text(json.dumps({k: v for k, v in doc.items()
                                 if k not in ("triads", "temperature")}))
    assert imucal.io.exports.read_export_input(plain).extras is None
    a = export_all(plain, tmp_path / "a")
    b = export_all(path, tmp_path / "b")
    for name in ("x.imu_tk_acc.calib", "x.imu_tk_gyro.calib", "x.fusion", "x.kalibr"):
        assert a[name] == b[name], name
    for name, data in a.items():
        assert not re.search(r"TC_|TCAL|CALTEMP|triad|thermal|CAL_ACC1|ACC2",
                             data.decode()), name
    for name in ("x.px4", "x.ardupilot", "x.c", "x.json", "x.yaml"):
        assert a[name] != b[name]


def test_instances_are_the_ones_the_streams_state():
    from imucal.io.exports.sections import instance_slots

    ulog = "acc sensor_accel:1 (ULog topic sensor_accel, multi-instance 1, fields x, y, z)"
    assert instance_slots(ulog, ["acc sensor_accel:0", "acc sensor_accel:2"]) == ([1, 0, 2], [])
    assert instance_slots("acc IMU (DataFlash message IMU)", ["acc IMU3"]) == ([0, 2], [])
    assert instance_slots("acc IMU[1] (x)", ["acc IMU[0]"]) == ([1, 0], [])
    assert instance_slots("the calibrated accelerometer", ["acc a2", "acc a3"]) == ([0, 1, 2], [])
    # Two streams stating one instance, or one stating none: calib.json's order, and said.
    slots, said = instance_slots("the calibrated accelerometer", ["acc a", "acc /imu2"])
    assert slots == [0, 1, 2] and "calib.json's order" in said[0]


def test_a_triad_of_several_segments_needs_the_segment(device, tmp_path):
    path, *_ = device
    doc = json.loads(path.read_text())
    entry = doc["triads"]["triads"][0]
    (seg,) = entry["segments"]
    mid = (seg["t_start"] + seg["t_end"]) / 2
    late = json.loads(json.dumps(seg)) | {"t_start": mid + 1.0}
    late["accelerometer"]["b"] = [0.01, 0.02, 0.03]
    entry["segments"] = [seg | {"t_end": mid}, late]
    entry.pop("temperature")  # its accelerometer then takes its segment's own model
    two = tmp_path / "two.json"
    two.write_text(json.dumps(doc))
    with pytest.raises(imucal.ImucalError, match=r"acc a2 has 2 segments .*--segment N"):
        export(two, "px4", tmp_path / "p")
    export(two, "ardupilot", tmp_path / "p", segment=1)  # the reference's one segment
    p = _ardupilot((tmp_path / "p").read_text())
    want = np.array(seg["accelerometer"]["b"]) * G_N  # the first half overlaps it longest
    assert np.allclose([p[f"INS_ACC2OFFS_{a}"] for a in "XYZ"], want, rtol=1e-12)


@pytest.mark.parametrize("change", [
    ("temperature", "accelerometer", "coefficients", [[1.0, 2.0]]),
    ("temperature", "gyroscope", "order", 5),
    ("temperature", "accelerometer", "span_degC", [40.0, 20.0]),
])
def test_a_damaged_section_is_one_line_naming_its_field(change, device, tmp_path):
    path, *_ = device
    doc = json.loads(path.read_text())
    sec, sensor, key, value = change
    doc[sec][sensor][key] = value
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc))
    with pytest.raises(imucal.ImucalError) as e:
        export(bad, "json", tmp_path / "x.json")
    assert e.value.field.startswith(f"{sec}.{sensor}.") and str(bad) in str(e.value)
