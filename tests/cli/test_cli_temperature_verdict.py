"""The run judged on the model apply uses (method.md §8, §12): with --temperature on a session
with a temperature ramp, the verdict, the held-out figure and the drift test (M7) are those of
the bias in temperature, the constant fit's figures beside them; without the flag the run is
judged as before, drift warning and all; a drift the temperature does not follow is still
said, and a span under 10 deg C keeps M7 as it was."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from imucal.stages.drift import ADVICE, ADVICE_IN_TEMPERATURE
from imucal.stages.verdict import DRIFT_NEXT

WARM_UP = DRIFT_NEXT[ADVICE]
IN_TEMPERATURE = "accelerometer with its bias in temperature (method.md M16)"


def _imucal(*args: str, cwd: Path) -> str:
    code = "import sys; from imucal.cli import main; sys.exit(main())"
    proc = subprocess.run([sys.executable, "-c", code, *args], cwd=cwd, capture_output=True,
                          text=True, timeout=300)
    assert "Traceback" not in proc.stderr, proc.stderr
    assert proc.returncode == 0, proc.stderr
    return proc.stdout


def _row(label: str, before: float, after: float, held: float, note: str) -> str:
    """A line of the summary's quality table, as imucal/cli/summary.py lays it out."""
    return f"{label:28s}{before:>10.3g}{after:>10.3g}{held:>10.3g}  ({note})"


@pytest.fixture(scope="module")
def ramp(tmp_path_factory) -> tuple[Path, str, dict, str, dict]:
    """A 15-45 deg C ramp, both biases linear in it (truth order 1), calibrated with and
    without --temperature: (folder, stdout, calib.json) each."""
    d = tmp_path_factory.mktemp("ramp")
    _imucal("synth", "lin.csv", "--temperature", "15", "45", "--temp-acc-bias", "0.4,-0.3,0.2",
            "--temp-gyro-bias", "0.005,-0.004,0.003", "--poses", "24", "--acc-rate", "200",
            "--seed", "5", cwd=d)
    heat = _imucal("calibrate", "lin.csv", "--out", "t.json", "--temperature", cwd=d)
    plain = _imucal("calibrate", "lin.csv", "--out", "c.json", cwd=d)
    return (d, heat, json.loads((d / "t.json").read_text()), plain,
            json.loads((d / "c.json").read_text()))


def test_with_temperature_the_ramp_is_good_and_nothing_moved(ramp):
    _, out, t, _, c = ramp
    v, f = t["verdict"], t["verdict"]["figures"]
    assert (v["level"], v["code"], v["caveats"]) == ("good", "good", [])
    assert v["model"] == IN_TEMPERATURE
    assert f["acc_held_out_mg"] <= 1.0
    # The constant fit's figures beside them: the run without the flag judged those.
    assert f["acc_held_out_mg_constant"] == c["verdict"]["figures"]["acc_held_out_mg"]
    assert f["acc_in_sample_mg_constant"] == c["verdict"]["figures"]["acc_in_sample_mg"]
    assert f["acc_held_out_mg_constant"] > 2.0 > 5 * f["acc_held_out_mg"]
    acc = t["temperature"]["accelerometer"]
    assert acc["order"] == 1  # the truth's
    assert acc["static_norm_rms_mg"] | {"note": None} == {
        "in_sample": f["acc_in_sample_mg"], "held_out": f["acc_held_out_mg"],
        "static_blocks": 24, "held_out_blocks": 22, "note": None,
        "constant": {"in_sample": c["quality"]["static_norm_rms_mg"]["after"],
                     "held_out": c["quality"]["static_norm_rms_mg"]["cross_validated"]}}
    # No drift warned: each bias moved with the temperature, which the model explains (said).
    assert not {w["code"] for w in t["warnings"]} & {"acc_bias_drift", "gyro_bias_drift"}
    assert "warm up" not in out and "moved during the recording" not in out
    for sensor, unit in (("accelerometer", "mg"), ("gyroscope", "deg/s")):
        (note,) = [n for n in t["temperature"][sensor]["notes"] if "steady bias" in n]
        m = re.fullmatch(rf"{sensor}: with a steady bias it moved about ([\d.]+) {unit} over "
                         r"the recording \(M7: F [\d.e+]+, p ([\d.e-]+)\); the bias of order 1 in "
                         r"temperature explains it \(a drift in time beyond it: F [\d.e+-]+, p "
                         r"([\d.e-]+)\): no drift warned", note)
        assert m, note
        assert float(m.group(2)) < 1e-3 < float(m.group(3))
    # The summary: the verdict first, both models' rows, the result line.
    lines = out.splitlines()
    assert lines[:2] == [
        "verdict         good: still poses the fit in temperature did not see are off by "
        f"{f['acc_held_out_mg']:.2g} mg; turns it did not see end "
        f"{f['gravity_held_out_deg']:.2g} deg off the measured gravity",
        "next step       none: the calibration is ready to use"]
    before = t["quality"]["static_norm_rms_mg"]["before"]
    i = lines.index(_row("static norm error (mg)", before, f["acc_in_sample_mg_constant"],
                         f["acc_held_out_mg_constant"],
                         "constant bias: |a| against |g| on the still poses, RMS"))
    assert lines[i + 1] == _row("  in temperature (mg)", before, f["acc_in_sample_mg"],
                                f["acc_held_out_mg"], "bias in temperature (M16), as apply "
                                "calibrates: the figures the verdict judges")
    (result,) = [ln for ln in lines if ln.startswith("result ")]
    assert result.startswith(
        f"result          good: accelerometer {f['acc_held_out_mg']:.3g} mg held out "
        f"({f['acc_in_sample_mg']:.3g} in-sample) with its bias in temperature, "
        f"{f['acc_held_out_mg_constant']:.3g} ({f['acc_in_sample_mg_constant']:.3g}) constant, ")


def test_without_temperature_the_same_ramp_still_warns(ramp):
    _, _, _, out, c = ramp
    v = c["verdict"]
    assert v["level"] == "usable with caveats"
    assert "model" not in v and "temperature" not in c
    assert set(v["figures"]) == {"acc_held_out_mg", "acc_in_sample_mg", "gravity_held_out_deg",
                                 "gravity_in_sample_deg"}
    found = {x["code"]: x for x in [v, *v["caveats"]]}
    for code, sensor in (("acc_bias_drift", "accelerometer"), ("gyro_bias_drift", "gyroscope")):
        (w,) = [w for w in c["warnings"] if w["code"] == code]
        assert w["message"].startswith(f"the {sensor}'s bias moved during the recording: about ")
        assert w["message"].endswith(f"; {ADVICE}")
        assert found[code]["next"] == WARM_UP
        assert found[code]["reason"] == w["message"].removesuffix(f"; {ADVICE}")
    lines = out.splitlines()
    assert not [ln for ln in lines if "in temperature" in ln]
    q = c["quality"]["static_norm_rms_mg"]
    assert _row("static norm error (mg)", q["before"], q["after"], q["cross_validated"],
                "|a| against |g| on the still poses, RMS") in lines


def test_a_drift_the_temperature_does_not_follow_is_still_said(ramp):
    d = ramp[0]
    raw = pl.read_csv(d / "lin.csv")
    t = raw["t"].to_numpy()
    # The same signals with a temperature that zigzags 20-40 deg C every 20 s: the biases'
    # drift, which followed the ramp, follows this one in no way.
    zig = 30.0 + 10.0 * np.sign(np.sin(2 * np.pi * t / 40.0))
    raw.with_columns(pl.Series("temp", zig)).write_csv(d / "zig.csv")
    _imucal("calibrate", "zig.csv", "--out", "z.json", "--temperature", cwd=d)
    z = json.loads((d / "z.json").read_text())
    v = z["verdict"]
    assert v["level"] == "usable with caveats" and v["model"] == IN_TEMPERATURE
    found = {x["code"]: x for x in [v, *v["caveats"]]}
    for code, sensor in (("acc_bias_drift", "accelerometer"), ("gyro_bias_drift", "gyroscope")):
        (w,) = [w for w in z["warnings"] if w["code"] == code]
        assert w["message"].startswith(f"the {sensor}'s bias moved during the recording beyond "
                                       "what its temperature explains: about ")
        assert w["message"].endswith(f"; {ADVICE_IN_TEMPERATURE}")
        assert found[code]["next"] == ("check that the temperature stream is the sensor's own, "
                                       "and keep the session short")
        (note,) = [n for n in z["temperature"][sensor]["notes"] if "steady bias" in n]
        assert "of it unexplained" in note and note.endswith("): warned")


def test_a_5_degC_span_keeps_the_drift_warning(tmp_path: Path):
    _imucal("synth", "s5.csv", "--temperature", "28", "33", "--temp-acc-bias", "0.5,-0.5,0.5",
            "--temp-gyro-bias", "0.02,-0.02,0.02", "--poses", "20", "--acc-rate", "200",
            "--seed", "5", cwd=tmp_path)
    out = _imucal("calibrate", "s5.csv", "--out", "s5.json", "--temperature", cwd=tmp_path)
    s5 = json.loads((tmp_path / "s5.json").read_text())
    (w,) = [w for w in s5["warnings"] if w["code"] == "acc_bias_drift"]
    assert w["message"].startswith("the accelerometer's bias moved during the recording: about ")
    assert w["message"].endswith(f"; {ADVICE}")
    assert out.splitlines()[:2] == [
        f"verdict         usable with caveats: {w['message'].removesuffix(f'; {ADVICE}')}",
        f"next step       {WARM_UP}"]
    assert not [n for n in s5["temperature"]["accelerometer"]["notes"] if "steady bias" in n]


def test_several_sessions_of_one_device_are_judged_on_the_pooled_model(tmp_path: Path):
    from imucal.synth import TemperatureProfile, make_session, random_acc_model, random_gyro_model

    rng = np.random.default_rng(9)
    acc, gyro = random_acc_model(rng), random_gyro_model(rng)
    for i, temp in enumerate((15.0, 30.0, 45.0)):  # one device, each session at one temperature
        session, _ = make_session(poses=12, seed=i, acc_rate=100.0, acc_truth=acc,
                                  gyro_truth=gyro, temperature=TemperatureProfile(
                                      start=temp, end=temp, acc=((4e-4, -3e-4, 2e-4),),
                                      gyro=((1e-4, 0, 0),)))
        table = {"t": session.t_acc, "temp": np.full(len(session.t_acc), temp)}
        for k, ax in enumerate("xyz"):
            table[f"a{ax}"], table[f"g{ax}"] = session.acc[:, k], session.gyro[:, k]
        pl.DataFrame(table).write_csv(tmp_path / f"t{i}.csv")
    out = _imucal("calibrate", "t0.csv", "--same-device", "t1.csv", "--same-device", "t2.csv",
                  "--out", "dev.json", cwd=tmp_path)
    d = json.loads((tmp_path / "dev.json").read_text())
    v, sn = d["verdict"], d["temperature"]["accelerometer"]["static_norm_rms_mg"]
    assert v["model"] == IN_TEMPERATURE
    # Every session's still poses, each held out of the pooled fit (none at an end alone).
    assert (sn["static_blocks"], sn["held_out_blocks"]) == (36, 36)
    assert (sn["held_out"], sn["in_sample"]) == (v["figures"]["acc_held_out_mg"],
                                                 v["figures"]["acc_in_sample_mg"])
    assert v["figures"]["acc_held_out_mg"] < 1.0
    # The constant fit's, of the first session alone, beside it; "before" not said of the pool.
    assert v["figures"]["acc_held_out_mg_constant"] == \
        d["quality"]["static_norm_rms_mg"]["cross_validated"]
    (row,) = [ln for ln in out.splitlines() if ln.startswith("  in temperature (mg)")]
    assert row.split()[3] == "n/a"
