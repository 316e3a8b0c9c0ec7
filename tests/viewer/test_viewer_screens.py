"""The recording as a person sees it: the native viewer (headless, software Vulkan) and the web
viewer served on 127.0.0.1 and rendered by headless Chromium.

Needs ``mesa-vulkan-drivers`` and ``chromium`` (Debian packages, installed by .ci/run): where
one is missing the test is skipped with a reason naming the package, except in CI, where it
fails (``tests/viewer_env.py``). Every process started here gets its own process
group and a private ``XDG_DATA_HOME`` (the viewer persists layouts there), and is ended by its
group id.
"""

from __future__ import annotations

import base64
import contextlib
import io
import json
import os
import re
import select
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from viewer_env import RERUN

import imucal
from viewer.app import free_port
from viewer.recording import save_recording

pytestmark = pytest.mark.viewer

WIDTH, HEIGHT = 1600, 1000
SHOTS = os.environ.get("IMUCAL_SCREENSHOT_DIR")  # keep the screenshots there, if set


@pytest.fixture(scope="module")
def sample_rrd(tmp_path_factory, sample_session_path) -> Path:
    result = imucal.calibrate(imucal.load_session(sample_session_path))
    path = tmp_path_factory.mktemp("screens") / "session.rrd"
    save_recording(result, path)
    return path


def _start(cmd: list[str], env: dict | None = None, **kw) -> subprocess.Popen:
    return subprocess.Popen(cmd, env=env, start_new_session=True, **kw)


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    else:  # the launcher exited; its child (the real binary) may still hold the group
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(proc.pid, signal.SIGKILL)


def _image(png: bytes) -> np.ndarray:
    from PIL import Image  # a dependency of rerun-sdk

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.float64)


def _richness(img: np.ndarray) -> tuple[float, int]:
    """Pixel standard deviation and the number of distinct colours (coarsely quantised)."""
    q = (img // 16).astype(np.int64)
    codes = q[..., 0] * 256 + q[..., 1] * 16 + q[..., 2]
    return float(img.std()), int(len(np.unique(codes)))


def _series_pixels(img: np.ndarray) -> int:
    """Pixels of the raw (orange) and calibrated (blue) magnitude lines in the left part of
    the window, where the Overview tab plots them."""
    left = img[:, : int(img.shape[1] * 0.6)]
    n = 0
    for rgb in ((0xFF, 0x7F, 0x0E), (0x1F, 0x77, 0xB4)):
        n += int(np.count_nonzero(np.abs(left - rgb).max(axis=-1) < 40))
    return n


def _keep(name: str, png: bytes) -> None:
    if SHOTS:
        Path(SHOTS).mkdir(parents=True, exist_ok=True)
        (Path(SHOTS) / name).write_bytes(png)


def _private_env(tmp_path: Path) -> dict:
    return dict(os.environ, XDG_DATA_HOME=str(tmp_path / "xdg"), RUST_LOG="warn")


# --- native viewer -------------------------------------------------------------------------------


def test_native_viewer_shows_every_tab_without_errors(native_viewer, sample_rrd, tmp_path):
    from rerun.experimental import ViewerClient

    port = free_port()
    proc = _start([str(RERUN), "--headless", "--bind", "127.0.0.1", "--port", str(port),
                   "--window-size", f"{WIDTH}x{HEIGHT}", "--hide-welcome-screen"],
                  env=_private_env(tmp_path), stdout=subprocess.DEVNULL,
                  stderr=open(tmp_path / "viewer.log", "w"))  # noqa: SIM115
    try:
        client = _connect(ViewerClient, port, proc, tmp_path)
        client.open([str(sample_rrd)])
        _wait(lambda: not client.get_state().loading, 30, "the recording to load")
        client.set_time("time", duration=80.0)
        bp = client.get_blueprint()
        tabs_key, tabs = next((k, v["ContainerBlueprint"]) for k, v in bp.blueprint.items()
                              if v.get("ContainerBlueprint", {}).get("container_kind") == "Tabs")
        names = [_display_name(bp.blueprint.get("/" + t, {})) or f"tab{i}"
                 for i, t in enumerate(tabs["contents"])]
        # The sweep and the optimiser plot on their own timelines: show those tabs on them too.
        other_timeline = {"L-curve": ("lambda", 10), "Optimiser": ("iteration", 1)}
        for i, tab in enumerate(tabs["contents"]):
            if i:  # show the next tab: the same layout with another active tab
                layout = json.loads(json.dumps(bp.blueprint))
                layout[tabs_key]["ContainerBlueprint"]["active_tab"] = tab
                client.set_blueprint(layout, store_id=bp.store_id)
            client.set_time("time", duration=80.0)
            time.sleep(2.0)
            png = client.take_screenshot()
            _keep(f"native_{i}_{names[i]}.png", png)
            img = _image(png)
            std, colours = _richness(img)
            assert std > 10 and colours > 30, (names[i], std, colours)
            if names[i] in other_timeline:
                timeline, at = other_timeline[names[i]]
                client.set_time(timeline, sequence=at)
                time.sleep(2.0)
                png = client.take_screenshot()
                _keep(f"native_{i}_{names[i]}_{timeline}.png", png)
                changed = np.abs(_image(png) - img).max(axis=-1) > 40
                assert changed.mean() > 0.01, f"{names[i]} on '{timeline}' draws nothing"
            state = client.get_state()
            for view in state.views:
                errors = [r for r in view.reports if r.severity.lower() == "error"]
                assert not errors, (view.name, errors)
        assert {"Overview", "Signals", "Gravity", "L-curve", "Optimiser"} <= set(names)
        assert len(state.views) >= 25
    finally:
        _stop(proc)


def _display_name(entry: dict) -> str | None:
    for archetype in ("ContainerBlueprint", "ViewBlueprint"):
        name = entry.get(archetype, {}).get("display_name")
        if name:
            return str(name)
    return None


def _connect(client_cls, port: int, proc: subprocess.Popen, tmp_path: Path):
    deadline = time.monotonic() + 30
    while True:
        if proc.poll() is not None:
            log = (tmp_path / "viewer.log").read_text()[-2000:]
            pytest.fail(f"the headless viewer exited ({proc.returncode}): {log}")
        try:
            client = client_cls.connect(f"rerun+http://127.0.0.1:{port}/proxy")
            client.get_state()
            return client
        except Exception:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.5)


def _wait(cond, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out waiting for {what}")
        time.sleep(0.5)


# --- web viewer ----------------------------------------------------------------------------------


class DevTools:
    """Chromium driven over ``--remote-debugging-pipe`` (NUL-separated JSON on fds 3 and 4):
    the DevTools protocol with the standard library only."""

    def __init__(self, chromium: str, profile: Path, log: Path):
        to_chrome_r, self._w = os.pipe()
        self._r, from_chrome_w = os.pipe()

        def wire() -> None:  # in the child, before exec: fd 3 = its input, fd 4 = its output
            os.dup2(to_chrome_r, 3)
            os.dup2(from_chrome_w, 4)

        cmd = [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
               "--no-first-run", "--disable-background-networking",
               "--disable-component-update", "--disable-sync", f"--user-data-dir={profile}",
               f"--window-size={WIDTH},{HEIGHT}", "--remote-debugging-pipe", "about:blank"]
        self.proc = subprocess.Popen(cmd, preexec_fn=wire, close_fds=False,  # noqa: PLW1509
                                     start_new_session=True, stdout=subprocess.DEVNULL,
                                     stderr=open(log, "w"))  # noqa: SIM115
        os.close(to_chrome_r)
        os.close(from_chrome_w)
        self._buf = b""
        self._id = 0

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

    def close(self) -> None:
        with contextlib.suppress(OSError):
            os.close(self._w)
        with contextlib.suppress(OSError):
            os.close(self._r)
        _stop(self.proc)


def test_web_viewer_renders_the_recording_in_chromium(chromium_path, sample_rrd, tmp_path):
    web_port = free_port()
    server = _start([sys.executable, "-c", "from imucal.cli import view_main; view_main()",
                     str(sample_rrd), "--web", "--port", str(web_port)],
                    env=_private_env(tmp_path), stdout=subprocess.PIPE,
                    stderr=open(tmp_path / "server.log", "w"), text=True)  # noqa: SIM115
    chrome = None
    try:
        line = server.stdout.readline()
        match = re.search(r"http://127\.0\.0\.1:\d+/\S*", line)
        assert match, f"no URL in {line!r}"
        url = match.group(0)
        _wait(lambda: _http_ok(f"http://127.0.0.1:{web_port}/"), 30, "the web viewer's server")

        chrome = DevTools(chromium_path, tmp_path / "profile", tmp_path / "chromium.log")
        target = chrome.call("Target.createTarget", {"url": url})["targetId"]
        session = chrome.call("Target.attachToTarget",
                              {"targetId": target, "flatten": True})["sessionId"]
        chrome.call("Emulation.setDeviceMetricsOverride",
                    {"width": WIDTH, "height": HEIGHT, "deviceScaleFactor": 1, "mobile": False},
                    session)

        def shot() -> bytes:
            for _ in range(10):  # the page may be between documents for a moment
                try:
                    data = chrome.call("Page.captureScreenshot", {"format": "png"}, session, 60)
                    return base64.b64decode(data["data"])
                except RuntimeError as e:
                    if "Not attached" not in str(e):
                        raise
                    time.sleep(1)
            raise RuntimeError("Chromium never had a page to capture")

        loading = shot()  # right after navigating: the loading screen
        _, loading_colours = _richness(_image(loading))
        deadline = time.monotonic() + 120
        png, drawn = loading, 0
        while time.monotonic() < deadline:  # until the plots show the data, not just the layout
            time.sleep(3)
            png = shot()
            drawn = _series_pixels(_image(png))
            if drawn > 2000:
                time.sleep(3)
                png = shot()
                break
        _keep("web.png", png)
        img = _image(png)
        std, colours = _richness(img)
        assert std > 10, "blank page"
        assert colours > max(4 * loading_colours, 60), (
            f"still the loading screen ({colours} colours vs {loading_colours})")
        assert _series_pixels(img) > 2000, f"the plots stayed empty ({drawn} pixels of the lines)"
    finally:
        if chrome is not None:
            chrome.close()
        _stop(server)


def _http_ok(url: str) -> bool:
    try:
        with urllib.request.urlopen(url, timeout=2) as r:
            return r.status == 200
    except OSError:
        return False
