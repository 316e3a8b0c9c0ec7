"""A calibration file no sensor could have is refused by every reader (issue 27): apply, every
export and the store read it through calibration_from_dict, in one line naming the file and the
field."""

from __future__ import annotations

import contextlib
import copy
import io
import json
import os
import signal
from pathlib import Path

import pytest

import imucal
from imucal.cli.main import main
from imucal.errors import ImucalError


@pytest.fixture(scope="module")
def good(tmp_path_factory, sample_session_path) -> dict:
    d = tmp_path_factory.mktemp("good")
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["calibrate", str(sample_session_path), "--out", str(d / "c.json")]) == 0
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    return json.loads((d / "c.json").read_text())


def _swap(doc: dict) -> dict:
    seg = doc["segments"][0]
    seg["accelerometer"], seg["gyroscope"] = seg["gyroscope"], seg["accelerometer"]
    return doc


def _k_b(doc: dict) -> dict:
    m = doc["segments"][0]["accelerometer"]
    m["K"], m["b"] = [0.03, 0.01, 0.05], m["K"]  # a bias of 10-50 mg as the scales
    return doc


def _set(path: list, value):
    def edit(doc: dict) -> dict:
        d = doc
        for k in path[:-1]:
            d = d[k]
        d[path[-1]] = value
        return doc
    return edit


ACC = ["segments", 0, "accelerometer"]
GYRO = ["segments", 0, "gyroscope"]
CASES = {
    "negative scale": (_set(ACC + ["K"], [1.0, -1.0, 1.0]), "segments[0].accelerometer.K",
                       "negative scale factor"),
    "K and b swapped": (_k_b, "segments[0].accelerometer.K", "are K and b swapped"),
    "sensors swapped": (_swap, "segments[0].accelerometer.T", "the gyroscope's model"),
    "bias 1e308": (_set(ACC + ["b"], [1e308, 0, 0]), "segments[0].accelerometer.b",
                   "beyond 10 g"),
    "gyro bias 50 rad/s": (_set(GYRO + ["b"], [50, 0, 0]), "segments[0].gyroscope.b",
                           "beyond 10 rad/s"),
    "scale 1e300": (_set(GYRO + ["K"], [1e300, 1e300, 1e300]), "segments[0].gyroscope.K",
                    "no scale from rad/s to rad/s"),
    "axes 100x apart": (_set(ACC + ["K"], [1.0, 1.0, 0.01]), "segments[0].accelerometer.K",
                        "differ by more than 10 times"),
    "misalignment 80 deg": (_set(GYRO + ["T"], [[1, 5.7, 0], [0, 1, 0], [0, 0, 1]]),
                            "segments[0].gyroscope.T", "beyond 45 degrees"),
    "g 1e300": (_set(["units", "g"], 1e300), "units.g", "is not a gravity"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_an_implausible_calibration_is_refused_by_every_reader(tmp_path, good, case,
                                                               sample_session_path):
    edit, field, needle = CASES[case]
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(edit(copy.deepcopy(good))))
    with pytest.raises(ImucalError) as e:
        imucal.load_calibration(path)
    msg = str(e.value)
    assert msg.startswith(f"{path}: {field}: ") and needle in msg and "\n" not in msg
    for args in (["apply", path, sample_session_path, "--out", tmp_path / "o.csv"],
                 ["export", path, "--to", "px4", "--out", tmp_path / "px4.params"]):
        err = io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            rc = main([str(a) for a in args])
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        assert rc == 1 and field in err.getvalue() and needle in err.getvalue(), args
    assert sorted(os.listdir(tmp_path)) == ["bad.json"]


def test_a_good_calibration_and_counts_pass(tmp_path, good):
    path = tmp_path / "c.json"
    path.write_text(json.dumps(good))
    assert imucal.load_calibration(path).segments[0].acc.K[0] == pytest.approx(1, abs=0.1)
    counts = copy.deepcopy(good)
    counts["units"]["accelerometer_raw"] = "counts"
    counts["segments"][0]["accelerometer"]["K"] = [1 / 4096, 1 / 4100, 1 / 4090]
    # An unsigned 16-bit converter of a +-16 g part: its zero 32768 counts, 16 g once calibrated.
    counts["segments"][0]["accelerometer"]["K"] = [1 / 2048, 1 / 2050, 1 / 2046]
    counts["segments"][0]["accelerometer"]["b"] = [32768.0, 32700.0, 32900.0]
    path.write_text(json.dumps(counts))
    assert imucal.load_calibration(Path(path)).acc_unit_raw == "counts"
    counts["segments"][0]["accelerometer"]["b"] = [1e308, 0, 0]
    path.write_text(json.dumps(counts))
    with pytest.raises(ImucalError, match="segments.0..accelerometer.b: bias b .* counts is "
                                          "beyond any converter"):
        imucal.load_calibration(path)
