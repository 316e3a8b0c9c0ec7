"""The Triads and Temperature tabs and the check's recording as a person sees them (headless
native viewer): every view of each has drawn data and none reports an error.
``IMUCAL_SCREENSHOT_DIR=docs`` keeps docs/tab-triads.png, docs/tab-temperature.png and
docs/check.png."""

from __future__ import annotations

import numpy as np
import pytest
from test_viewer_screens import (
    MIN_DRAWN,
    _keep,
    _show_tab,
    _tab_until_drawn,
    _tabs,
    _wait,
    headless_viewer,
)

import imucal
from imucal.inuse.check import Stored, check
from imucal.inuse.everyday import Drift, make_everyday
from imucal.pipeline import calibrate_temperature, calibrate_triads
from imucal.stages.apply import Calibration, SegmentModels
from imucal.synth import SecondTriad, TemperatureProfile, make_session
from viewer.inuse import save_check_recording
from viewer.recording import save_recording

pytestmark = pytest.mark.viewer


def _errors(client) -> list:
    return [(v.name, r.summary) for v in client.get_state().views
            if v.visible for r in v.reports if r.severity.lower() == "error"]


def _blank(shares: dict) -> list:
    return [(v[2], round(s, 5)) for v, s in shares.items() if s < MIN_DRAWN.get(v[1], 0.002)]


def test_native_viewer_draws_the_triads_and_temperature_tabs(native_viewer, tmp_path):
    session, _ = make_session(
        poses=24, seed=1, second_acc=(SecondTriad(rotation_deg=3.0, gyro=True),),
        temperature=TemperatureProfile(back=True))
    result = calibrate_triads(calibrate_temperature(imucal.calibrate(session)),
                              temperature=True)
    rrd = tmp_path / "tt.rrd"
    save_recording(result, rrd)
    with headless_viewer(tmp_path) as client:
        client.open([str(rrd)])
        _wait(lambda: not client.get_state().loading, 30, "the recording to load")
        bp = client.get_blueprint()
        tabs = _tabs(bp.blueprint)
        assert [name for _, name, _ in tabs][-3:] == ["Triads", "Temperature", "Summary"]
        for name, shot, views_expected in (("Triads", "tab-triads.png", 4),
                                           ("Temperature", "tab-temperature.png", 8)):
            ref, _, views = next(t for t in tabs if t[1] == name)
            assert len(views) == views_expected
            _show_tab(client, bp, ref)
            png, shares = _tab_until_drawn(client, views)
            _keep(shot, png)
            assert not _blank(shares), (name, shares)
            assert not _errors(client), _errors(client)


def test_native_viewer_draws_the_checks_recording(native_viewer, tmp_path):
    session, truth = make_everyday("walk", minutes=10, seed=1, drift=Drift(
        gyro_bias=np.radians([0.3, -0.25, 0.2]), acc_bias=np.array([0.006, -0.004, 0.005])))
    cal = Calibration(segments=(SegmentModels(0.0, 0.0, truth.stored_acc, truth.stored_gyro),),
                      acc_unit_raw="g", acc_unit="g", g=1.0, gyro_unit_raw="rad/s")
    rrd = tmp_path / "check.rrd"
    save_check_recording(check(cal, Stored(0.3, 0.0003), session), cal, session, rrd)
    with headless_viewer(tmp_path) as client:
        client.open([str(rrd)])
        _wait(lambda: not client.get_state().loading, 30, "the recording to load")
        layout = client.get_blueprint().blueprint
        names = [v["ContainerBlueprint"].get("display_name") for v in layout.values()
                 if "ContainerBlueprint" in v]
        assert "Check" in names and "Refresh" not in names  # one tab: no Tabs container
        views = [(k.split("/")[-1], v["ViewBlueprint"]["class_identifier"],
                  v["ViewBlueprint"].get("display_name", "")) for k, v in layout.items()
                 if "ViewBlueprint" in v]
        assert len(views) == 8
        png, shares = _tab_until_drawn(client, views)
        _keep("check.png", png)
        assert not _blank(shares), shares
        assert not _errors(client), _errors(client)
