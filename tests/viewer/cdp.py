"""Chromium driven over ``--remote-debugging-pipe`` (NUL-separated JSON on fds 3 and 4): the
DevTools protocol with the standard library only, for tests/test_viewer_screens.py."""

from __future__ import annotations

import base64
import contextlib
import json
import os
import select
import subprocess
import time
from pathlib import Path

from viewer_env import stop_group


class DevTools:
    """A headless Chromium with one page: open a URL, screenshot it, click in it."""

    def __init__(self, chromium: str, profile: Path, log: Path, width: int, height: int):
        to_chrome_r, self._w = os.pipe()
        self._r, from_chrome_w = os.pipe()

        def wire() -> None:  # in the child, before exec: fd 3 = its input, fd 4 = its output
            os.dup2(to_chrome_r, 3)
            os.dup2(from_chrome_w, 4)

        cmd = [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
               "--no-first-run", "--disable-background-networking",
               "--disable-component-update", "--disable-sync", f"--user-data-dir={profile}",
               f"--window-size={width},{height}", "--remote-debugging-pipe", "about:blank"]
        self.proc = subprocess.Popen(cmd, preexec_fn=wire, close_fds=False,  # noqa: PLW1509
                                     start_new_session=True, stdout=subprocess.DEVNULL,
                                     stderr=open(log, "w"))  # noqa: SIM115
        os.close(to_chrome_r)
        os.close(from_chrome_w)
        self._buf = b""
        self._id = 0
        self.size = (width, height)
        self.session: str | None = None

    def call(self, method: str, params: dict | None = None, session: str | None = None,
             timeout: float = 30.0) -> dict:
        self._id += 1
        msg = {"id": self._id, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        os.write(self._w, json.dumps(msg).encode() + b"\0")
        deadline = time.monotonic() + timeout
        while True:
            reply = self._read(deadline)
            if reply.get("id") == self._id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply.get("result", {})

    def _read(self, deadline: float) -> dict:
        while b"\0" not in self._buf:
            left = deadline - time.monotonic()
            ready, _, _ = select.select([self._r], [], [], max(left, 0))
            if not ready:
                raise TimeoutError("no answer from Chromium")
            chunk = os.read(self._r, 1 << 20)
            if not chunk:
                raise EOFError("Chromium closed the pipe")
            self._buf += chunk
        raw, self._buf = self._buf.split(b"\0", 1)
        return json.loads(raw)

    def open(self, url: str) -> None:
        """A page on ``url`` at the window's size (device scale 1)."""
        target = self.call("Target.createTarget", {"url": url})["targetId"]
        self.session = self.call("Target.attachToTarget",
                                 {"targetId": target, "flatten": True})["sessionId"]
        w, h = self.size
        self.call("Emulation.setDeviceMetricsOverride",
                  {"width": w, "height": h, "deviceScaleFactor": 1, "mobile": False},
                  self.session)
        # A headless page never has the focus; the web viewer reads input only when focused.
        self.call("Emulation.setFocusEmulationEnabled", {"enabled": True}, self.session)

    def screenshot(self) -> bytes:
        for _ in range(10):  # the page may be between documents for a moment
            try:
                data = self.call("Page.captureScreenshot", {"format": "png"}, self.session, 60)
                return base64.b64decode(data["data"])
            except RuntimeError as e:
                if "Not attached" not in str(e):
                    raise
                time.sleep(1)
        raise RuntimeError("Chromium never had a page to capture")

    def next_frame(self) -> None:
        """Return once the page has begun a new animation frame."""
        self.call("Runtime.evaluate", {
            "expression": "new Promise(r => requestAnimationFrame(() => r(0)))",
            "awaitPromise": True}, self.session)

    def click(self, x: float, y: float) -> None:
        """A left click at (x, y) CSS pixels: move there, press, release, each in its own
        frame of the page (the web viewer, egui, misses a press and a release that arrive in
        one frame: egui issue 5770)."""
        self.call("Input.dispatchMouseEvent", {"type": "mouseMoved", "x": x, "y": y},
                  self.session)
        self.next_frame()
        for kind, buttons in (("mousePressed", 1), ("mouseReleased", 0)):
            self.call("Input.dispatchMouseEvent", {"type": kind, "x": x, "y": y,
                                                   "button": "left", "buttons": buttons,
                                                   "clickCount": 1}, self.session)
            self.next_frame()
            # and a second apart: under a software rasterizer a frame of the Overview (every
            # still block's gravity arrows in 3D) can outlast next_frame's wait, and egui then
            # sees the press and the release together and drops the click
            time.sleep(float(os.environ.get("CLICK_GAP", "1.0")))

    def close(self) -> None:
        with contextlib.suppress(OSError):
            os.close(self._w)
        with contextlib.suppress(OSError):
            os.close(self._r)
        stop_group(self.proc)
