"""The live view as a person sees it while capturing: a headless native viewer (software
Vulkan) receives a capture of a synthetic device over gRPC as it happens, and every view of
the layout must have drawn data, mid-capture (during a turn, with 12 poses held and the turn's
rate against its limit) and at the end (``IMUCAL_SCREENSHOT_DIR=docs`` keeps docs/live.png and
docs/live-view.png, what README shows). Needs mesa-vulkan-drivers: skipped without it, failed
in CI."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
import rerun as rr
from test_viewer_screens import _image, _keep, _shot, drawn, headless_viewer

from imucal.capture.detector import MIN_HOLD_S
from imucal.capture.run import capture
from imucal.capture.send import frames_of, paced
from imucal.capture.sources import FdSource
from imucal.capture.stop import PRESETS
from imucal.synth import make_session
from viewer.live import LiveView, blueprint

pytestmark = pytest.mark.viewer


def test_live_view_draws_while_capturing(tmp_path, native_viewer):
    import os

    session, _ = make_session(poses=40, seed=3)
    head, frames = frames_of(session, "lines")
    with headless_viewer(tmp_path) as client:
        live = LiveView.new(MIN_HOLD_S)
        live.rec.set_sinks(rr.GrpcSink(client.url),
                           default_blueprint=blueprint())
        r, w = os.pipe()

        def device() -> None:
            with os.fdopen(w, "wb") as out:
                def send(chunk):
                    out.write(b"".join(chunk))
                    out.flush()

                send(head)
                paced(session.t_acc, frames, 8.0, send)  # a turn lasts 0.25 s

        dev = threading.Thread(target=device, daemon=True)
        dev.start()
        done: list = []
        run = threading.Thread(target=lambda: done.append(capture(
            FdSource(r), tmp_path / "D", PRESETS["default"], until=60, on_batch=live.batch,
            on_status=live.status)), daemon=True)
        run.start()
        # Mid-capture: a turn under way after 12 poses, its rate known (the view at 10 Hz).
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not done:
            st = live.state
            peak = ((st.turn or {}).get("turn_peak_dps") or 0) if st is not None else 0
            if st is not None and st.orientations >= 12 and st.state == "moving" and peak > 30:
                break
            time.sleep(0.02)
        assert not done, "the capture ended before the 12th pose's turn"
        time.sleep(0.15)  # the view's next send, the turn still under way
        mid = _shot(client)
        run.join(60)
        live.close()
        assert done and done[0].stopped == "targets met"
        png = _shot(client)
    for shot, name in ((mid, "live.png"), (png, "live-view.png")):
        img = _image(shot)
        assert drawn(img, "2D") > 0.002  # the signals and the detector's plots
        assert np.isfinite(img).all()
        _keep(name, shot)
