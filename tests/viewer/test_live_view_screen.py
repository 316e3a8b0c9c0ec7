"""The live view as a person sees it while capturing: a headless native viewer (software
Vulkan) receives a capture of a synthetic device over gRPC as it happens, and every view of
the layout must have drawn data (``IMUCAL_SCREENSHOT_DIR=docs`` keeps docs/live-view.png,
what README shows). Needs mesa-vulkan-drivers: skipped without it, failed in CI."""

from __future__ import annotations

import threading

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
                paced(session.t_acc, frames, 25.0, send)

        dev = threading.Thread(target=device, daemon=True)
        dev.start()
        report = capture(FdSource(r), tmp_path / "D", PRESETS["default"], until=60,
                         on_batch=live.batch, on_status=live.status)
        live.close()
        assert report.stopped == "targets met"
        png = _shot(client)
    img = _image(png)
    assert drawn(img, "2D") > 0.002  # the signals and the detector's plots
    _keep("live-view.png", png)
    assert np.isfinite(img).all()
