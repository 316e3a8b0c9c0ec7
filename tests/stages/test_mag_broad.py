"""The BROAD trials' heading against the optical reference (issue 23): the field turned into the
optical East-North-Up frame by ``opt_quat`` keeps one horizontal direction if it is right;
its spread over the trial, raw and calibrated by imucal's own fit of the trial
(bench/mag_broad.py, whose figures bench/mag_broad.md reports)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

_spec = importlib.util.spec_from_file_location(
    "mag_broad", Path(__file__).resolve().parents[2] / "bench" / "mag_broad.py")
mag_broad = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(mag_broad)


@pytest.fixture(scope="module")
def trials(shared_data):
    return {r["trial"][:2]: r for r in (mag_broad.trial(p) for p in
                                        sorted((shared_data / "broad").glob("*.hdf5")))}


def test_the_calibrated_heading_is_never_worse_than_the_raw_beyond_its_error(trials):
    """Heading RMS over the trial, deg (measured: 02 3.06 raw, 3.16 calibrated; 05 3.08,
    3.02; 24 4.41, 3.91). This IMU's magnetometer comes calibrated by its maker (hard iron
    under 1.3 uT of 44, soft iron within 2 %) and the lab's field is not uniform (the norm
    varies by 1.7-1.8 % after any fit): on 02 the trial's own fit is 0.10 deg worse, 1.1 of
    the difference's standard errors (jackknife over 20 pieces of the trial), no real loss but
    no gain; on 05 and 24 it is better by 3 and 4.5 of them."""
    for key in ("02", "05", "24"):
        r = trials[key]
        assert 2.5 < r["raw_rms"] < 5.0 and r["coverage"] > 0.8 and not r["disturbances"]
        assert r["cal_rms"] - r["raw_rms"] == pytest.approx(r["diff"])
        assert r["diff"] < 2 * r["diff_se"], key  # never worse beyond the figure's own error
    assert trials["05"]["diff"] < -2 * trials["05"]["diff_se"]
    assert trials["24"]["diff"] < -3 * trials["24"]["diff_se"]
    assert trials["24"]["cal_p99"] < trials["24"]["raw_p99"] - 1.0  # the worst moments too
    # the magnetometer runs 14-18 ms behind the optical reference: the same for both
    for key in ("02", "05", "24"):
        assert 10 < trials[key]["lag_ms"] < 25
        assert trials[key]["lag_raw_rms"] < trials[key]["raw_rms"]


def test_trial_32s_magnet_is_found_and_the_trial_not_figured(trials):
    r = trials["32"]
    assert "cal_rms" not in r and "directions" in r["unfit"]
    [step] = r["disturbances"]
    assert step.startswith("at 38.2 s the field stepped by 57.9 uT while the sensor was still")
    assert r["raw_rms"] > 40  # the magnet rides with the sensor: the raw heading is lost
