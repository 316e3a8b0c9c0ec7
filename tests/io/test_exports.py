"""Every export round-trips: the target tool's own equation, written here from its documentation
(not imported from imucal), applied to raw samples must give what ``imucal apply`` gives, or
differ from it by no more than the loss the export states.

- imu_tk:    X' = T K (X - B), from the three triads of the .calib file (CalibratedTriad_).
- fusion:    i_c = M (s ⊙ (i_u - b)) (FusionCalibrationInertial), in g and deg/s; in numpy and
             compiled with gcc against a stand-in of Fusion's types.
- kalibr:    a_meas = M_a a_i + b_a, w_meas = M_g C_gyro_i w_i + b_g (IccScaledMisalignedImu),
             inverted, then rotated into imucal's frame with the stated R_c_i.
- px4:       (a_m - CAL_ACC0_xOFF) * CAL_ACC0_xSCALE, in m/s^2 (Accelerometer::Correct).
- ardupilot: (accel - INS_ACCOFFS) * INS_ACCSCAL, in m/s^2 (_rotate_and_correct_accel).
- c:         the generated header compiled with gcc, two segments and the gap between them.
- json/yaml: x = A (x_raw - b) per piece as the file's own "model" text says; the YAML read by
             a small reader here (no YAML library is a dependency).
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import imucal
from imucal.io.exports import export
from imucal.synth import make_session

G_N = 9.80665
ROOT = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
IMUCAL = shutil.which("imucal", path=str(BIN)) or str(BIN / "imucal")
GCC = shutil.which("gcc") or shutil.which("cc")
needs_gcc = pytest.mark.skipif(GCC is None, reason="no C compiler (gcc or cc) on PATH")


# --- fixtures ------------------------------------------------------------------------------------


def _calibrated(tmp: Path, name: str, **kw):
    session, truth = make_session(**kw)
    result = imucal.calibrate(session)
    path = tmp / f"{name}.json"
    imucal.save_calibration(result, path)
    return path, session, result, truth


@pytest.fixture(scope="module")
def one(tmp_path_factory):
    """One segment, accelerometer in g, gyroscope in rad/s."""
    return _calibrated(tmp_path_factory.mktemp("one"), "calib", poses=26, seed=3)


@pytest.fixture(scope="module")
def si(tmp_path_factory):
    """One segment, accelerometer in m/s^2 (|g| = 9.80665)."""
    return _calibrated(tmp_path_factory.mktemp("si"), "calib", poses=26, seed=4,
                       acc_unit="m/s^2")


@pytest.fixture(scope="module")
def two(tmp_path_factory):
    """Two segments: the parameters change half-way (method.md §2)."""
    out = _calibrated(tmp_path_factory.mktemp("two"), "calib", poses=40, seed=5,
                      change_at=0.5)
    assert len(out[2].segments) == 2, "the synthetic change must give two segments"
    return out


def _apply(path: Path, session):
    return imucal.load_calibration(path).apply(session)


# --- imu_tk ---------------------------------------------------------------------------------------


def _read_imu_tk(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CalibratedTriad_::load: 9 numbers (T row-major), 9 (K row-major), 3 (B)."""
    text = path.read_text()
    blocks = [b for b in text.strip().split("\n\n")]
    assert [len(b.splitlines()) for b in blocks] == [3, 3, 3], text  # as save() lays it out
    v = np.array(text.split(), dtype=float)
    assert v.size == 21
    return v[:9].reshape(3, 3), v[9:18].reshape(3, 3), v[18:]


def test_imu_tk_round_trip(one, tmp_path):
    path, session, _, _ = one
    res = export(path, "imu_tk", tmp_path / "dev")
    assert [p.name for p, _ in res.files] == ["dev_acc.calib", "dev_gyro.calib"]
    want = _apply(path, session)
    for name, raw, ref in (("dev_acc.calib", session.acc, want.acc),
                           ("dev_gyro.calib", session.gyro, want.gyro)):
        T, K, B = _read_imu_tk(tmp_path / name)
        assert np.allclose(np.diag(T), 1.0) and np.count_nonzero(K - np.diag(np.diag(K))) == 0
        got = (T @ K @ (raw - B).T).T  # X' = T K (X - B)
        assert np.max(np.abs(got - ref)) < 1e-12 * max(1.0, np.abs(ref).max())


# --- x-io Fusion ----------------------------------------------------------------------------------


def _fusion_constants(text: str) -> dict[str, np.ndarray]:
    out = {}
    for kind, name, body in re.findall(
            r"static const (FusionMatrix|FusionVector) (\w+) = \{([^}]*)\};", text):
        vals = np.array([float(x.rstrip("f")) for x in body.split(",")])
        out[name] = vals.reshape(3, 3) if kind == "FusionMatrix" else vals
    return out


@pytest.mark.parametrize("which", ["one", "si"])
def test_fusion_round_trip_in_numpy(which, request, tmp_path):
    path, session, _, _ = request.getfixturevalue(which)
    export(path, "fusion", tmp_path / "fusion.h")
    c = _fusion_constants((tmp_path / "fusion.h").read_text())
    want = _apply(path, session)
    # Fusion's units: accelerometer in g (input and output), gyroscope in deg/s.
    acc_in = session.acc / (G_N if session.acc_unit == "m/s^2" else 1.0)
    acc_ref = want.acc / (G_N if want.acc_unit == "m/s^2" else 1.0)
    gyro_in = np.degrees(session.gyro)
    gyro_ref = np.degrees(want.gyro)
    for prefix, u, ref in (("imucalAccelerometer", acc_in, acc_ref),
                           ("imucalGyroscope", gyro_in, gyro_ref)):
        M, s, b = (c[prefix + k] for k in ("Misalignment", "Sensitivity", "Offset"))
        got = (M @ (s * (u - b)).T).T  # i_c = M (s ⊙ (i_u - b))
        scale = np.abs(ref).max()
        assert np.max(np.abs(got - ref)) < 2e-6 * scale  # float constants: ~7 digits


_FUSION_STANDIN = r"""
/* A stand-in for Fusion.h: its types and FusionCalibrationInertial as documented
 * (FusionMath.h, FusionCalibration.h): i_c = M (s * (i_u - b)), row-major matrix. */
typedef union { float array[3]; struct { float x, y, z; } axis; } FusionVector;
typedef union { float array[3][3]; struct { float xx, xy, xz, yx, yy, yz, zx, zy, zz; } element; }
    FusionMatrix;
static inline FusionVector FusionCalibrationInertial(const FusionVector u, const FusionMatrix m,
                                                     const FusionVector s, const FusionVector b) {
    FusionVector h, r; int i;
    for (i = 0; i < 3; i++) h.array[i] = (u.array[i] - b.array[i]) * s.array[i];
    for (i = 0; i < 3; i++)
        r.array[i] = m.array[i][0] * h.array[0] + m.array[i][1] * h.array[1]
                   + m.array[i][2] * h.array[2];
    return r;
}
"""

_FUSION_MAIN = r"""
#include <stdio.h>
#include "export.h"
int main(void) {
    char which; float x, y, z;
    while (scanf(" %c %f %f %f", &which, &x, &y, &z) == 4) {
        FusionVector u = {{x, y, z}}, c;
        c = which == 'a'
            ? FusionCalibrationInertial(u, imucalAccelerometerMisalignment,
                                        imucalAccelerometerSensitivity, imucalAccelerometerOffset)
            : FusionCalibrationInertial(u, imucalGyroscopeMisalignment,
                                        imucalGyroscopeSensitivity, imucalGyroscopeOffset);
        printf("%.9g %.9g %.9g\n", c.axis.x, c.axis.y, c.axis.z);
    }
    return 0;
}
"""


def _compile(tmp: Path, sources: dict[str, str], *flags: str) -> Path:
    for name, text in sources.items():
        (tmp / name).write_text(text)
    exe = tmp / "a.out"
    proc = subprocess.run([GCC, "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic",
                           "-Wno-missing-braces", *flags, "-o", str(exe), str(tmp / "main.c"),
                           "-lm"], capture_output=True, text=True, cwd=tmp, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return exe


@needs_gcc
def test_fusion_header_compiles_and_matches(one, tmp_path):
    path, session, _, _ = one
    export(path, "fusion", tmp_path / "fusion.h")
    text = (tmp_path / "fusion.h").read_text().replace('#include "Fusion.h"', _FUSION_STANDIN)
    exe = _compile(tmp_path, {"export.h": text, "main.c": _FUSION_MAIN})
    idx = np.arange(0, len(session.acc), 97)
    lines = [f"a {x:.9g} {y:.9g} {z:.9g}" for x, y, z in session.acc[idx]]
    lines += [f"g {x:.9g} {y:.9g} {z:.9g}" for x, y, z in np.degrees(session.gyro[idx])]
    out = subprocess.run([str(exe)], input="\n".join(lines), capture_output=True, text=True,
                         timeout=60).stdout
    got = np.array(out.split(), dtype=float).reshape(-1, 3)
    want = _apply(path, session)
    ref = np.vstack([want.acc[idx], np.degrees(want.gyro[idx])])
    assert np.allclose(got[:len(idx)], ref[:len(idx)], atol=1e-5)  # g
    assert np.allclose(got[len(idx):], ref[len(idx):], atol=1e-3)  # deg/s, float32


# --- Kalibr ---------------------------------------------------------------------------------------


def _yaml_scalar(text: str):
    text = text.strip()
    if text in ("null", "~", ""):
        return None
    if text in ("true", "false"):
        return text == "true"
    if text in (".nan", ".inf", "-.inf"):
        return float(text.replace(".", ""))
    return json.loads(text)  # quoted strings, numbers, flow lists of numbers


def _strip_comment(line: str) -> str:
    quoted = False
    for i, ch in enumerate(line):
        if ch == '"' and (i == 0 or line[i - 1] != "\\"):
            quoted = not quoted
        elif ch == "#" and not quoted and (i == 0 or line[i - 1] in " \t"):
            return line[:i].rstrip()
    return line.rstrip()


def read_yaml(text: str) -> dict:
    """The block YAML the exports write: mappings, '- ' sequences of mappings, flow lists."""
    rows = []
    for raw in text.splitlines():
        line = _strip_comment(raw)
        if line.strip():
            rows.append((len(line) - len(line.lstrip()), line.strip()))

    def block(i: int, indent: int):
        if rows[i][1].startswith("- "):
            items = []
            while i < len(rows) and rows[i][0] == indent and rows[i][1].startswith("- "):
                # the item's first key sits 2 columns right of the dash
                rows[i] = (indent + 2, rows[i][1][2:])
                item, i = block(i, indent + 2)
                items.append(item)
            return items, i
        out = {}
        while i < len(rows) and rows[i][0] == indent and not rows[i][1].startswith("- "):
            key, _, rest = rows[i][1].partition(":")
            key = json.loads(key) if key.startswith('"') else key
            i += 1
            if rest.strip():
                out[key] = _yaml_scalar(rest)
            elif i < len(rows) and rows[i][0] > indent:
                out[key], i = block(i, rows[i][0])
            else:
                out[key] = None
        return out, i

    doc, end = block(0, rows[0][0])
    assert end == len(rows), rows[end:]
    return doc


# YAML 1.1's float (PyYAML, used by Kalibr): a dot, and a signed exponent if any.
_YAML11_FLOAT = re.compile(r"^[-+]?([0-9][0-9_]*)?\.[0-9.]*([eE][-+][0-9]+)?$")


def _yaml11_floats_ok(text: str) -> None:
    for tok in re.findall(r"(?<![\w.\"])[-+]?\d[\d.]*(?:[eE][-+]?\d+)?(?![\w\"])",
                          "\n".join(_strip_comment(x) for x in text.splitlines())):
        if "." in tok or "e" in tok.lower():
            assert _YAML11_FLOAT.match(tok), tok


@pytest.mark.parametrize("which", ["one", "si"])
def test_kalibr_round_trip(which, request, tmp_path):
    path, session, _, _ = request.getfixturevalue(which)
    export(path, "kalibr", tmp_path / "imu.yaml")
    text = (tmp_path / "imu.yaml").read_text()
    _yaml11_floats_ok(text)
    y = read_yaml(text)
    assert y["model"] == "scale-misalignment"
    Ma = np.array(y["accelerometers"]["M"])
    Mg = np.array(y["gyroscopes"]["M"])
    C = np.array(y["gyroscopes"]["C_gyro_i"])
    R = np.array(y["imucal"]["R_c_i"])
    assert np.allclose(np.triu(Ma, 1), 0) and np.allclose(np.triu(Mg, 1), 0)  # lower triangular
    for rot in (C, R):
        assert np.allclose(rot @ rot.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(rot) == pytest.approx(1.0, abs=1e-12)
    assert np.allclose(y["gyroscopes"]["A"], 0)
    # Kalibr's measurement model, inverted: a_i = M_a^-1 (a_meas - b_a), in m/s^2 and rad/s.
    per = G_N if session.acc_unit == "g" else 1.0
    a_meas = session.acc * per
    a_i = np.linalg.solve(Ma, (a_meas - np.array(y["imucal"]["accelerometer_bias"])).T).T
    w_i = np.linalg.solve(Mg @ C, (session.gyro - np.array(y["imucal"]["gyroscope_bias"])).T).T
    want = _apply(path, session)
    a_ref = want.acc * (G_N if want.acc_unit == "g" else 1.0)
    assert np.max(np.abs(a_i @ R.T - a_ref)) < 1e-10 * np.abs(a_ref).max()
    assert np.max(np.abs(w_i @ R.T - want.gyro)) < 1e-10 * np.abs(want.gyro).max()
    # The noise block: the calibration's still-block white noise, largest axis, in SI units.
    noise = json.loads(path.read_text())["noise"]
    unit = G_N if noise["accelerometer"]["unit"] == "g" else 1.0
    assert y["accelerometer_noise_density"] == pytest.approx(
        max(noise["accelerometer"]["white_noise_density"]) * unit, rel=1e-12)
    assert y["gyroscope_noise_density"] == pytest.approx(
        max(noise["gyroscope"]["white_noise_density"]), rel=1e-12)
    assert y["update_rate"] == pytest.approx(session.acc_rate, rel=1e-6)
    assert "accelerometer_random_walk" not in y  # not determined by 3-second blocks: a comment
    assert "# accelerometer_random_walk: not determined" in text


def test_kalibr_lq_decomposition_recovers_a_lower_triangular_model(tmp_path, one):
    """A calibration whose inverse is already lower triangular needs no rotation."""
    from imucal.io.exports.kalibr import kalibr_intrinsics, lq

    rng = np.random.default_rng(0)
    L = np.tril(rng.normal(0, 0.02, (3, 3))) + np.diag([1.02, 0.97, 1.01])
    k = kalibr_intrinsics(np.linalg.inv(L), None, 1.0)
    assert np.allclose(k["M_a"], L, atol=1e-14) and np.allclose(k["R_c_i"], np.eye(3))
    X = rng.normal(size=(3, 3)) + 3 * np.eye(3)
    L2, Q = lq(X)
    assert np.allclose(L2 @ Q, X) and np.all(np.diag(L2) > 0) and np.allclose(Q @ Q.T, np.eye(3))


# --- PX4 and ArduPilot ----------------------------------------------------------------------------


def _px4_params(text: str) -> dict[str, float]:
    out = {}
    for line in text.splitlines():
        if line.startswith("#") or not line.strip():
            continue
        vehicle, comp, name, value, ptype = line.split("\t")
        assert (vehicle, comp, ptype) == ("1", "1", "9")  # float parameters of vehicle 1
        out[name] = float(value)
    return out


def _ardupilot_params(text: str) -> dict[str, float]:
    out = {}
    for line in text.splitlines():
        if line.startswith("#") or not line.strip():
            continue
        name, value = line.split(",")
        out[name] = float(value)
    return out


def _stated_mg(text: str) -> tuple[float, float]:
    m = re.search(r"leaves ([\d.e+-]+) mg RMS, ([\d.e+-]+) mg at most", text)
    assert m, text
    return float(m.group(1)), float(m.group(2))


def _diagonal_outputs(fmt: str, text: str, session) -> tuple[np.ndarray, np.ndarray]:
    """The autopilot's own correction, offset first then scale, in m/s^2 and rad/s."""
    per = G_N if session.acc_unit == "g" else 1.0
    a_m = session.acc * per
    if fmt == "px4":
        p = _px4_params(text)
        off = np.array([p[f"CAL_ACC0_{a}OFF"] for a in "XYZ"])
        scale = np.array([p[f"CAL_ACC0_{a}SCALE"] for a in "XYZ"])
        goff = np.array([p[f"CAL_GYRO0_{a}OFF"] for a in "XYZ"])
    else:
        p = _ardupilot_params(text)
        off = np.array([p[f"INS_ACCOFFS_{a}"] for a in "XYZ"])
        scale = np.array([p[f"INS_ACCSCAL_{a}"] for a in "XYZ"])
        goff = np.array([p[f"INS_GYROFFS_{a}"] for a in "XYZ"])
    return (a_m - off) * scale, session.gyro - goff


@pytest.mark.parametrize("fmt", ["px4", "ardupilot"])
@pytest.mark.parametrize("which", ["one", "si"])
def test_autopilot_matches_up_to_the_stated_loss(fmt, which, request, tmp_path):
    path, session, result, truth = request.getfixturevalue(which)
    out = tmp_path / "params"
    export(path, fmt, out)
    text = out.read_text()
    acc, gyro = _diagonal_outputs(fmt, text, session)
    want = _apply(path, session)
    g_si = result.calibration.g * (G_N if want.acc_unit == "g" else 1.0)
    ref = want.acc * (G_N if want.acc_unit == "g" else 1.0)
    rms, worst = _stated_mg(text)
    # Still samples (the synthetic poses, away from their edges): every one within the stated
    # worst case over the sphere, and the stated RMS of the right size.
    still = np.zeros(len(session.t_acc), bool)
    for a, b in truth.pose_times:
        still |= (session.t_acc > a + 0.3) & (session.t_acc < b - 0.3)
    err = np.linalg.norm(acc[still] - ref[still], axis=1) / g_si * 1000.0
    assert err.max() <= worst * 1.02 + 0.05
    assert 0.3 * rms < np.sqrt(np.mean(err**2)) < 3.0 * rms
    assert rms > 1.0  # the synthetic misalignment (0.01 rad) is not negligible
    # Gyroscope: offsets only, and exactly the calibration's bias.
    assert np.allclose(session.gyro - gyro, result.segments[0].gyro.model.b)


@pytest.mark.parametrize("fmt", ["px4", "ardupilot"])
def test_autopilot_is_exact_without_misalignment(fmt, one, tmp_path):
    """With T = I the diagonal model is the whole model: no loss, and the loss says 0."""
    path, session, _, _ = one
    data = json.loads(path.read_text())
    for seg in data["segments"]:
        seg["accelerometer"]["T"] = np.eye(3).tolist()
    flat = tmp_path / "flat.json"
    flat.write_text(json.dumps(data))
    export(flat, fmt, tmp_path / "params")
    text = (tmp_path / "params").read_text()
    acc, _ = _diagonal_outputs(fmt, text, session)
    want = _apply(flat, session)
    assert np.allclose(acc, want.acc * G_N, rtol=1e-12, atol=1e-12)
    assert max(_stated_mg(text)) < 1e-9  # rounding only


# --- C header -------------------------------------------------------------------------------------


_C_MAIN = r"""
#include <stdio.h>
#include "export.h"
int main(void) {
    char which; double t, x, y, z;
    while (scanf(" %c %lf %lf %lf %lf", &which, &t, &x, &y, &z) == 5) {
        imucal_real raw[3] = {(imucal_real)x, (imucal_real)y, (imucal_real)z}, out[3];
        if (which == 'a') imucal_calibrate_accelerometer(t, raw, out);
        else imucal_calibrate_gyroscope(t, raw, out);
        printf("%.17g %.17g %.17g\n", (double)out[0], (double)out[1], (double)out[2]);
    }
    return 0;
}
"""


def _run_c(exe: Path, session, idx_a: np.ndarray, idx_g: np.ndarray) -> np.ndarray:
    def row(which: str, t: np.ndarray, x: np.ndarray, i: int) -> str:
        return " ".join([which, *(repr(float(v)) for v in (t[i], *x[i]))])  # exact doubles

    lines = [row("a", session.t_acc, session.acc, i) for i in idx_a]
    lines += [row("g", session.t_gyro, session.gyro, i) for i in idx_g]
    out = subprocess.run([str(exe)], input="\n".join(lines), capture_output=True, text=True,
                         timeout=60).stdout
    return np.array(out.split(), dtype=float).reshape(-1, 3)


@needs_gcc
@pytest.mark.parametrize("real", ["double", "float"])
def test_c_header_compiles_and_matches_apply_across_segments(two, real, tmp_path):
    path, session, result, _ = two
    export(path, "c", tmp_path / "export.h")
    exe = _compile(tmp_path, {"main.c": _C_MAIN}, f"-DIMUCAL_REAL={real}")
    want = _apply(path, session)
    # Samples in both segments, in the gap between them, and at the pieces' very edges.
    s0, s1 = result.calibration.segments
    edges = [s0.t_end, s1.t_start]
    idx = np.unique(np.concatenate([np.arange(0, len(session.t_acc), 53),
                                    *[np.searchsorted(session.t_acc, e) + np.arange(-2, 3)
                                      for e in edges]]))
    idx = idx[(idx >= 0) & (idx < len(session.t_acc))]
    assert np.any((session.t_acc[idx] > s0.t_end) & (session.t_acc[idx] < s1.t_start))
    got = _run_c(exe, session, idx, idx)
    tol = 1e-12 if real == "double" else 2e-6
    ref = np.vstack([want.acc[idx], want.gyro[idx]])
    scale = np.abs(ref).max(axis=0)
    assert np.all(np.abs(got - ref) <= tol * np.maximum(scale, 1.0))


@needs_gcc
def test_c_header_on_a_sample_exactly_at_a_segment_end(two, tmp_path):
    """A segment owns its closed interval (imucal apply's searchsorted): at t = t_end the
    segment's model, one ulp later the mean of the two."""
    path, session, result, _ = two
    export(path, "c", tmp_path / "export.h")
    exe = _compile(tmp_path, {"main.c": _C_MAIN})
    s0, s1 = result.calibration.segments
    t = np.array([s0.t_end, np.nextafter(s0.t_end, np.inf)])
    raw = np.array([[0.1, -0.2, 0.98], [0.1, -0.2, 0.98]])
    fake = imucal.Session(acc=raw, t_acc=t, gyro=raw * 0.1, t_gyro=t)
    got = _run_c(exe, fake, np.arange(2), np.arange(2))
    want = _apply(path, fake)
    assert np.allclose(got[:2], want.acc, rtol=1e-14, atol=1e-14)
    assert not np.allclose(want.acc[0], want.acc[1])  # two different models indeed


# --- JSON and YAML --------------------------------------------------------------------------------


def _apply_pieces(doc: dict, sensor: str, t: np.ndarray, raw: np.ndarray) -> np.ndarray:
    """The rule the file states in words: 'segment' pieces hold on [t_start, t_end], 'between'
    pieces on (t_start, t_end); the first piece also before, the last also after."""
    pieces = doc["pieces"]
    out = np.full(raw.shape, np.nan)
    for i, p in enumerate(pieces):
        lo, hi = p["t_start"], p["t_end"]
        if p["kind"] == "segment":
            inside = (t >= lo) & (t <= hi)
        else:
            inside = (t > lo) & (t < hi)
        if i == 0:
            inside |= t < lo
        if i == len(pieces) - 1:
            inside |= t > hi
        A, b = np.array(p[sensor]["A"]), np.array(p[sensor]["b"])
        out[inside] = (raw[inside] - b) @ A.T
    assert not np.isnan(out).any()
    return out


@pytest.mark.parametrize("fmt", ["json", "yaml"])
def test_plain_exports_round_trip_across_segments(two, fmt, tmp_path):
    path, session, _, _ = two
    out = tmp_path / f"export.{fmt}"
    export(path, fmt, out)
    text = out.read_text()
    doc = json.loads(text) if fmt == "json" else read_yaml(text)
    if fmt == "yaml":
        _yaml11_floats_ok(text)
    assert doc["units"]["accelerometer"] == "g" and doc["units"]["gyroscope"] == "rad/s"
    assert [p["kind"] for p in doc["pieces"]] == ["segment", "between", "segment"]
    want = _apply(path, session)
    acc = _apply_pieces(doc, "accelerometer", session.t_acc, session.acc)
    gyro = _apply_pieces(doc, "gyroscope", session.t_gyro, session.gyro)
    assert np.allclose(acc, want.acc, rtol=1e-13, atol=1e-13)
    assert np.allclose(gyro, want.gyro, rtol=1e-13, atol=1e-13)
    # A = T K, and the noise figures travel with their units.
    for p in doc["pieces"]:
        m = p["accelerometer"]
        assert np.allclose(np.array(m["T"]) * np.array(m["K"]), m["A"], rtol=1e-15)
    assert doc["noise"]["accelerometer"]["white_noise_density_unit"] == "g/sqrt(Hz)"


# --- refusals and the command line ----------------------------------------------------------------


def test_one_model_formats_need_a_segment_when_there_are_several(two, tmp_path):
    path = two[0]
    segs = json.loads(path.read_text())["segments"]
    listed = ", ".join(f"{i} ({s['t_start']:.1f}-{s['t_end']:.1f} s)"
                       for i, s in enumerate(segs, start=1))
    with pytest.raises(imucal.ImucalError, match="choose one with --segment N") as e:
        export(path, "px4", tmp_path / "p")
    assert listed in str(e.value) and not (tmp_path / "p").exists()
    res = export(path, "px4", tmp_path / "p", segment=2)
    assert any("segment 2 of 2" in n for n in res.notes)
    with pytest.raises(imucal.ImucalError, match=f"segment 3 does not exist; the segments are "
                                                  f"{re.escape(listed)}"):
        export(path, "imu_tk", tmp_path / "q", segment=3)


def test_counts_are_refused_where_the_target_wants_si_units(tmp_path):
    path, session, _, _ = _calibrated(tmp_path, "counts", poses=24, seed=6, acc_unit="counts")
    for fmt in ("px4", "ardupilot", "kalibr"):
        with pytest.raises(imucal.ImucalError, match="raw counts"):
            export(path, fmt, tmp_path / f"x.{fmt}")
    # Formats that take raw counts still work, and exactly.
    export(path, "imu_tk", tmp_path / "c")
    T, K, B = _read_imu_tk(tmp_path / "c_acc.calib")
    want = _apply(path, session)
    assert np.allclose((T @ K @ (session.acc - B).T).T, want.acc, rtol=1e-12, atol=1e-12)


@pytest.mark.skipif(not Path(IMUCAL).exists(), reason="the imucal script is not installed")
def test_cli_export_then_apply_agree(one, tmp_path):
    path, session, _, _ = one
    from imucal.io.export import write_session_mat

    sess_path = tmp_path / "s.mat"
    write_session_mat(sess_path, session)
    run = [subprocess.run([IMUCAL, *args], capture_output=True, text=True, cwd=tmp_path,
                          timeout=120) for args in (
        ["apply", str(path), str(sess_path), "--out", "cal.csv"],
        ["export", str(path), "--to", "json", "--out", "e.json"],
        ["export", str(path), "--to", "nonsense"])]
    assert run[0].returncode == 0, run[0].stderr
    assert run[1].returncode == 0 and "wrote e.json" in run[1].stdout, run[1].stderr
    assert run[2].returncode == 2 and "expected one of" in run[2].stderr
    import polars as pl

    cal = pl.read_csv(tmp_path / "cal.csv")
    doc = json.loads((tmp_path / "e.json").read_text())
    got = _apply_pieces(doc, "accelerometer", cal["t"].to_numpy(), session.acc)
    assert np.allclose(got, cal.select("ax", "ay", "az").to_numpy(), rtol=1e-12, atol=1e-12)


def test_every_format_is_registered_and_documented():
    from imucal.cli.tools import FORMAT_NAMES
    from imucal.io.exports import FORMATS

    assert tuple(FORMATS) == FORMAT_NAMES
    readme = (ROOT / "README.md").read_text()
    section = readme[readme.index("## Exports"):]
    for fmt in FORMATS:
        assert f"`{fmt}`" in section, fmt
