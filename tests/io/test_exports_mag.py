"""The magnetometer in the exports (issue 23 item 6): each target's own equation, written here
from its source (not imported from imucal), applied to the raw field must give calib.json's
model ``m = R_am M (m_raw - b)`` (MagFit.apply), or differ from it by exactly the rotation the
export states.

- ardupilot: m = S (R_o m_mG + COMPASS_OFS), S from COMPASS_DIA/ODI (AP_Compass_Backend:
             rotate_field, then correct_field: ``mag += offsets; mag = mat * mag``), in mG;
             R_o from ArduPilot's Vector3::rotate, written out below for the codes used.
- px4:       m = R_o (S (m_G - CAL_MAG0_xOFF)) (calibration::Magnetometer::Correct), in gauss;
             R_o = Dcm(Euler(roll, pitch, yaw)) of PX4's rot_lookup row.
- fusion:    m = softIronMatrix (m_u - hardIronOffset) (FusionCalibrationMagnetic), float.
- c:         the generated header compiled with gcc: imucal_calibrate_magnetometer.
- json/yaml: m = A (m_raw - b) as the file's own "model" text says.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from export_files import FILE_FORMATS, export_all

import imucal
from imucal.io.exports import export
from imucal.synth import make_session
from tests.io.test_exports import _FUSION_STANDIN, _compile, needs_gcc, read_yaml

H = 0.70710678118654757  # ArduPilot's HALF_SQRT_2


def _ap_rotate(code: int, v: np.ndarray) -> np.ndarray:
    """ArduPilot's Vector3::rotate for the codes these tests meet, as its source writes them."""
    x, y, z = v.T
    if code == 0:
        return v.copy()
    if code == 2:  # ROTATION_YAW_90: tmp = x; x = -y; y = tmp;
        return np.column_stack([-y, x, z])
    if code == 9:  # ROTATION_ROLL_180_YAW_45: tmp = H*(x + y); y = H*(x - y); x = tmp; z = -z;
        return np.column_stack([H * (x + y), H * (x - y), -z])
    if code == 10:  # ROTATION_ROLL_180_YAW_90: tmp = x; x = y; y = tmp; z = -z;
        return np.column_stack([y, x, -z])
    raise AssertionError(f"rotation {code} is not written out in this test")


def _px4_dcm(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """matrix::Dcm(Euler(roll, pitch, yaw)): body <- sensor, 3-2-1 (PX4's get_rot_matrix)."""
    r, p, y = np.radians([roll, pitch, yaw])
    cp, sp, cr, sr, cy, sy = np.cos(p), np.sin(p), np.cos(r), np.sin(r), np.cos(y), np.sin(y)
    return np.array([[cp * cy, -cr * sy + sr * sp * cy, sr * sy + cr * sp * cy],
                     [cp * sy, cr * cy + sr * sp * sy, -sr * cy + cr * sp * sy],
                     [-sp, sr * cp, cr * cp]])


PX4_LOOKUP = {0: (0, 0, 0), 2: (0, 0, 90), 9: (180, 0, 45), 10: (180, 0, 90)}


def _rotvec(axis, deg: float) -> np.ndarray:
    """Rodrigues: the rotation of ``deg`` about ``axis``."""
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    t = np.radians(deg)
    return np.eye(3) + np.sin(t) * K + (1 - np.cos(t)) * K @ K


@pytest.fixture(scope="module")
def mag(tmp_path_factory):
    """One segment and a calibrated magnetometer (gauss, 50 Hz, R_am as fitted)."""
    tmp = tmp_path_factory.mktemp("mag")
    session, truth = make_session(poses=26, seed=3, mag_rate=50)
    result = imucal.calibrate(session)
    assert result.magnetometer is not None and result.magnetometer.R_am is not None
    path = tmp / "calib.json"
    imucal.save_calibration(result, path)
    raw = session.others[0].values
    assert session.others[0].kind == "mag" and session.others[0].unit == "gauss"
    return path, session, result, raw


def _model(doc: dict, raw: np.ndarray) -> np.ndarray:
    """calib.json's model, from its numbers: m = R_am M (m_raw - b)."""
    s = doc["magnetometer"]
    return (raw - np.array(s["b"])) @ (np.array(s["R_am"]) @ np.array(s["M"])).T


def _with_mag(path: Path, tmp: Path, name: str, **changes) -> Path:
    doc = json.loads(path.read_text())
    doc["magnetometer"].update(changes)
    out = tmp / name
    out.write_text(json.dumps(doc))
    return out


def _params(text: str, sep: str) -> dict[str, str]:
    out = {}
    for line in text.splitlines():
        if line.startswith("#") or not line.strip():
            continue
        parts = line.split(sep)
        if sep == "\t":
            assert parts[:2] == ["1", "1"] and parts[4] == ("6" if parts[2].endswith("_ROT")
                                                            else "9"), line
            out[parts[2]] = parts[3]
        else:
            out[parts[0]] = parts[1]
    return out


def _ardupilot_field(p: dict[str, str], raw_gauss: np.ndarray) -> np.ndarray:
    v = lambda k: float(p[k])  # noqa: E731
    S = np.array([[v("COMPASS_DIA_X"), v("COMPASS_ODI_X"), v("COMPASS_ODI_Y")],
                  [v("COMPASS_ODI_X"), v("COMPASS_DIA_Y"), v("COMPASS_ODI_Z")],
                  [v("COMPASS_ODI_Y"), v("COMPASS_ODI_Z"), v("COMPASS_DIA_Z")]])
    ofs = np.array([v(f"COMPASS_OFS_{a}") for a in "XYZ"])
    mag = _ap_rotate(int(p["COMPASS_ORIENT"]), raw_gauss * 1000.0)  # the driver's mG, rotated
    return (mag + ofs) @ S.T  # mag += offsets; mag = mat * mag


def _px4_field(p: dict[str, str], raw_gauss: np.ndarray) -> np.ndarray:
    v = lambda k: float(p[k])  # noqa: E731
    S = np.array([[v("CAL_MAG0_XSCALE"), v("CAL_MAG0_XODIAG"), v("CAL_MAG0_YODIAG")],
                  [v("CAL_MAG0_XODIAG"), v("CAL_MAG0_YSCALE"), v("CAL_MAG0_ZODIAG")],
                  [v("CAL_MAG0_YODIAG"), v("CAL_MAG0_ZODIAG"), v("CAL_MAG0_ZSCALE")]])
    off = np.array([v(f"CAL_MAG0_{a}OFF") for a in "XYZ"])
    R = _px4_dcm(*PX4_LOOKUP[int(p["CAL_MAG0_ROT"])])
    return (raw_gauss - off) @ S.T @ R.T  # _rotation * (_scale * (data - _offset))


def _stated(text: str, name: str) -> tuple[int, float]:
    m = re.search(rf"{name} = (\d+), the enumerated rotation nearest R_am \(a turn of "
                  r"[\d.e+-]+ deg\), leaves a residual rotation of ([\d.e+-]+) deg", text)
    assert m, text
    return int(m.group(1)), float(m.group(2))


def _angle(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))


@pytest.mark.parametrize("fmt", ["ardupilot", "px4"])
def test_autopilot_field_is_imucals_turned_by_the_stated_rotation(fmt, mag, tmp_path):
    """R_am as fitted (a few degrees from the identity): the orientation is 0 and what is left
    is R_am itself; every sample's field is imucal's turned back by R_am, to 1e-12."""
    path, _, result, raw = mag
    out = tmp_path / "p"
    export(path, fmt, out)
    text = out.read_text()
    p = _params(text, "," if fmt == "ardupilot" else "\t")
    got = _ardupilot_field(p, raw) / 1000.0 if fmt == "ardupilot" else _px4_field(p, raw)
    want = result.magnetometer.apply(raw)  # gauss, in the accelerometer's frame
    assert np.allclose(want, _model(json.loads(path.read_text()), raw), rtol=0, atol=1e-12)
    R = result.magnetometer.R_am
    code, angle = _stated(text, "COMPASS_ORIENT" if fmt == "ardupilot" else "CAL_MAG0_ROT")
    assert code == 0 and angle == pytest.approx(_angle(R), abs=6e-3)  # printed with 3 digits
    assert 1.0 < angle < 10.0  # the synthetic R_am is a few degrees: not negligible
    assert np.max(np.abs(got @ R.T - want)) < 1e-12 * np.abs(want).max()
    # The field's size comes out in the target's unit: |m| = the fitted field (0.5 gauss).
    assert np.median(np.linalg.norm(got, axis=1)) == pytest.approx(0.5, rel=0.01)


@pytest.mark.parametrize("code", [2, 9, 10])
@pytest.mark.parametrize("fmt", ["ardupilot", "px4"])
def test_autopilot_picks_the_nearest_orientation_and_states_the_rest(fmt, code, mag, tmp_path):
    """A magnetometer mounted at an enumerated rotation and then 2.5 deg off it: the export
    names that rotation, and its field is imucal's turned by exactly the 2.5 deg it states."""
    path, _, _, raw = mag
    R_code = _ap_rotate(code, np.eye(3)).T if fmt == "ardupilot" else _px4_dcm(*PX4_LOOKUP[code])
    delta = _rotvec([0.3, -1.0, 0.6], 2.5)
    turned = _with_mag(path, tmp_path, "calib.json", R_am=(delta @ R_code).tolist())
    out = tmp_path / "p"
    res = export(turned, fmt, out)
    text = out.read_text()
    got_code, angle = _stated(text, "COMPASS_ORIENT" if fmt == "ardupilot" else "CAL_MAG0_ROT")
    assert got_code == code and angle == pytest.approx(2.5, abs=5e-3)
    assert any("residual rotation of 2.5 deg" in n for n in res.notes)  # printed, too
    p = _params(text, "," if fmt == "ardupilot" else "\t")
    assert int(p["COMPASS_ORIENT" if fmt == "ardupilot" else "CAL_MAG0_ROT"]) == code
    got = _ardupilot_field(p, raw) / 1000.0 if fmt == "ardupilot" else _px4_field(p, raw)
    want = _model(json.loads(turned.read_text()), raw)
    assert np.max(np.abs(got @ delta.T - want)) < 1e-12 * np.abs(want).max()


def test_autopilot_without_r_am_or_a_physical_unit(mag, tmp_path):
    path, _, result, raw = mag
    no_r = _with_mag(path, tmp_path, "nor.json", R_am=None)
    export(no_r, "ardupilot", tmp_path / "a")
    text = (tmp_path / "a").read_text()
    p = _params(text, ",")
    assert "COMPASS_ORIENT" not in p and "holds no R_am" in text
    p["COMPASS_ORIENT"] = "0"  # the sensor's own frame
    fit = result.magnetometer
    want = (raw - fit.b) @ fit.M.T
    assert np.allclose(_ardupilot_field(p, raw) / 1000.0, want, rtol=0, atol=1e-12)
    counts = _with_mag(path, tmp_path, "counts.json", unit="counts")
    for fmt in ("ardupilot", "px4"):
        res = export(counts, fmt, tmp_path / fmt)
        text = (tmp_path / fmt).read_text()
        assert not re.search(r"^(1\t1\t)?(COMPASS_|CAL_MAG0_)", text, re.M)
        assert any("fitted on counts" in n and "not written" in n for n in res.notes)
    # uT: the same field, the offsets in the target's unit.
    ut = _with_mag(path, tmp_path, "ut.json", unit="uT",
                   b=(fit.b * 100.0).tolist())
    export(ut, "px4", tmp_path / "u")
    p = _params((tmp_path / "u").read_text(), "\t")
    assert [float(p[f"CAL_MAG0_{a}OFF"]) for a in "XYZ"] == pytest.approx(fit.b, rel=1e-12)


def test_fusion_soft_iron_has_the_rotation_folded_in(mag, tmp_path):
    path, _, result, raw = mag
    export(path, "fusion", tmp_path / "f.h")
    text = (tmp_path / "f.h").read_text()
    c = {}
    for kind, name, body in re.findall(
            r"static const (FusionMatrix|FusionVector) (\w+) = \{([^}]*)\};", text):
        v = np.array([float(x.rstrip("f")) for x in body.split(",")])
        c[name] = v.reshape(3, 3) if kind == "FusionMatrix" else v
    got = (raw - c["imucalHardIronOffset"]) @ c["imucalSoftIronMatrix"].T
    want = result.magnetometer.apply(raw)
    assert np.max(np.abs(got - want)) < 2e-6 * np.abs(want).max()  # float: ~7 digits
    assert "imucalAccelerometerMisalignment" in c  # the rest is still there


_FUSION_MAGNETIC = r"""
/* FusionCalibrationMagnetic as Fusion's FusionCalibration.h writes it. */
static inline FusionVector FusionCalibrationMagnetic(const FusionVector u, const FusionMatrix s,
                                                     const FusionVector h) {
    FusionVector d, r; int i;
    for (i = 0; i < 3; i++) d.array[i] = u.array[i] - h.array[i];
    for (i = 0; i < 3; i++)
        r.array[i] = s.array[i][0] * d.array[0] + s.array[i][1] * d.array[1]
                   + s.array[i][2] * d.array[2];
    return r;
}
"""

_FUSION_MAG_MAIN = r"""
#include <stdio.h>
#include "export.h"
int main(void) {
    float x, y, z;
    while (scanf(" %f %f %f", &x, &y, &z) == 3) {
        FusionVector u = {{x, y, z}};
        FusionVector c = FusionCalibrationMagnetic(u, imucalSoftIronMatrix, imucalHardIronOffset);
        printf("%.9g %.9g %.9g\n", c.axis.x, c.axis.y, c.axis.z);
    }
    return 0;
}
"""


@needs_gcc
def test_fusion_header_compiles_with_the_magnetometer(mag, tmp_path):
    import subprocess

    path, _, result, raw = mag
    export(path, "fusion", tmp_path / "fusion.h")
    text = (tmp_path / "fusion.h").read_text().replace(
        '#include "Fusion.h"', _FUSION_STANDIN + _FUSION_MAGNETIC)
    exe = _compile(tmp_path, {"export.h": text, "main.c": _FUSION_MAG_MAIN})
    idx = np.arange(0, len(raw), 41)
    out = subprocess.run([str(exe)], input="\n".join(" ".join(f"{v:.9g}" for v in raw[i])
                                                       for i in idx),
                         capture_output=True, text=True, timeout=60).stdout
    got = np.array(out.split(), dtype=float).reshape(-1, 3)
    want = result.magnetometer.apply(raw[idx])
    assert np.max(np.abs(got - want)) < 2e-6 * np.abs(want).max()  # float arithmetic


_C_MAG_MAIN = r"""
#include <stdio.h>
#include "export.h"
int main(void) {
    double x, y, z;
    while (scanf(" %lf %lf %lf", &x, &y, &z) == 3) {
        imucal_real raw[3] = {(imucal_real)x, (imucal_real)y, (imucal_real)z}, out[3];
        imucal_calibrate_magnetometer(raw, out);
        printf("%.17g %.17g %.17g\n", (double)out[0], (double)out[1], (double)out[2]);
    }
    return IMUCAL_HAS_MAGNETOMETER == 1 ? 0 : 1;
}
"""


@needs_gcc
def test_c_header_calibrates_the_magnetometer(mag, tmp_path):
    import subprocess

    path, _, result, raw = mag
    export(path, "c", tmp_path / "export.h")
    text = (tmp_path / "export.h").read_text()
    for name in ("imucal_mag_M", "imucal_mag_b", "imucal_mag_R_am"):
        assert f"static const imucal_real {name}[" in text
    exe = _compile(tmp_path, {"main.c": _C_MAG_MAIN})
    idx = np.arange(0, len(raw), 37)
    out = subprocess.run([str(exe)], input="\n".join(" ".join(repr(float(v)) for v in raw[i])
                                                       for i in idx),
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0
    got = np.array(out.stdout.split(), dtype=float).reshape(-1, 3)
    want = result.magnetometer.apply(raw[idx])
    assert np.max(np.abs(got - want)) < 1e-12 * np.abs(want).max()


@pytest.mark.parametrize("fmt", ["json", "yaml"])
def test_plain_exports_carry_the_magnetometer(fmt, mag, tmp_path):
    path, _, result, raw = mag
    export(path, fmt, tmp_path / f"e.{fmt}")
    text = (tmp_path / f"e.{fmt}").read_text()
    doc = json.loads(text) if fmt == "json" else read_yaml(text)
    m = doc["magnetometer"]
    assert m["unit"] == "gauss"
    got = (raw - np.array(m["b"])) @ np.array(m["A"]).T  # m = A (m_raw - b)
    want = result.magnetometer.apply(raw)
    assert np.allclose(got, want, rtol=0, atol=1e-13)
    assert np.allclose(np.array(m["R_am"]) @ np.array(m["M"]), m["A"], rtol=0, atol=1e-15)


def test_without_a_calibrated_magnetometer_the_exports_are_unchanged(mag, tmp_path):
    """No section, or one that says calibrated: false, give the same bytes in every format;
    and the section adds lines to the autopilot files without changing any other."""
    path, *_ = mag
    doc = json.loads(path.read_text())
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    without = tmp_path / "a" / "calib.json"
    without.write_text(json.dumps({k: v for k, v in doc.items() if k != "magnetometer"}))
    failed = tmp_path / "b" / "calib.json"
    failed.write_text(json.dumps(doc | {"magnetometer": {"calibrated": False, "unit": "gauss",
                                                          "M": "not a matrix"}}))
    a = export_all(without, tmp_path / "a" / "out")
    b = export_all(failed, tmp_path / "b" / "out")
    assert a == b and len(a) == len(FILE_FORMATS) + 1  # imu_tk writes two files
    for name, data in a.items():
        text = data.decode()
        assert not re.search(r"COMPASS|CAL_MAG|magnetometer|SoftIron|imucal_mag", text), name
    with_mag = export_all(path, tmp_path / "m")
    assert with_mag.keys() == a.keys()
    for name in ("x.ardupilot", "x.px4"):
        old, new = a[name].decode().splitlines(), with_mag[name].decode().splitlines()
        added = [x for x in new if x not in old]
        assert [x for x in new if x in old] == old  # every old line kept, in order
        assert added and all(re.search(r"magnetometer|compass|COMPASS_|CAL_MAG0_", x)
                             for x in added), added
