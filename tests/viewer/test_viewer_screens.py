"""The recording as a person sees it: the native viewer (headless, software Vulkan) opens each
tab of the stored layout and every panel in it must have drawn data; the web viewer, served on
127.0.0.1 and rendered by headless Chromium, is clicked through its tabs.

Needs ``mesa-vulkan-drivers`` (or a GPU's Vulkan driver) and ``chromium``: Debian packages,
installed by .ci/run. Where one is missing the test is skipped with a reason naming the
package, except in CI, where it fails (the ``native_viewer`` and ``chromium_path`` fixtures,
``tests/viewer_env.py``; requested first, so the skip comes before any recording is made).
One viewer process per recording, every tab shown in it in turn. Every process started here
gets its own process group and a private ``XDG_DATA_HOME`` (the viewer persists layouts
there), and is ended by its group id.

``IMUCAL_SCREENSHOT_DIR=docs`` keeps each tab's screenshot (what README shows).
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import subprocess
import sys
import time
import urllib.request
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from cdp import DevTools  # tests/cdp.py
from viewer_env import RERUN, need, stop_group

import imucal
from imucal.synth import make_session
from viewer.app import free_port
from viewer.recording import save_recording

pytestmark = pytest.mark.viewer

WIDTH, HEIGHT = 1600, 1000
SHOTS = os.environ.get("IMUCAL_SCREENSHOT_DIR")  # keep the tabs' screenshots there, if set
# What the viewer says when it finds no renderer after all (it panics after these words).
NO_RENDERER = ("Failed to get render context", "No graphics adapter", "No suitable adapter")


# --- recordings ----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def recordings(tmp_path_factory, sample_session_path) -> dict[str, Path]:
    """The sample, and a session in raw ADC counts (no nominal scale: no 'before' figures)."""
    out = tmp_path_factory.mktemp("screens")
    counts, _ = make_session(poses=30, seed=3, acc_unit="counts", gyro_unit="counts")
    paths = {}
    for name, session in (("sample", imucal.load_session(sample_session_path)),
                          ("counts", counts)):
        paths[name] = out / f"{name}.rrd"
        save_recording(imucal.calibrate(session), paths[name])
    return paths


# --- pixels --------------------------------------------------------------------------------------


def _image(png: bytes) -> np.ndarray:
    from PIL import Image  # a dependency of rerun-sdk

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.int16)


def _colourful(img: np.ndarray) -> np.ndarray:
    """Pixels of a series' colour: saturated, not the greys of text, grid, axes and cursor."""
    return (img.max(axis=-1) - img.min(axis=-1) > 60) & (img.max(axis=-1) > 90)


def _near(img: np.ndarray, rgb: int, tol: int = 30) -> np.ndarray:
    c = np.array([(rgb >> 24) & 255, (rgb >> 16) & 255, (rgb >> 8) & 255])
    return np.abs(img - c).max(axis=-1) < tol


def drawn(img: np.ndarray, view_class: str) -> float:
    """The share of a view's pixels that show data: text for a document, the measured gravity
    arrow's green in 3D (the body axes are always drawn), series colours elsewhere."""
    if view_class == "TextDocument":
        return float((img.max(axis=-1) > 150).mean())
    if view_class == "3D":
        from viewer.columns import MEASURED

        return float(_near(img, MEASURED).mean())
    return float(_colourful(img).mean())


MIN_DRAWN = {"TextDocument": 0.005, "3D": 0.0005}  # else 0.002: a curve of ~1 px over a plot


def _keep(name: str, png: bytes, width: int = 1200) -> None:
    """A tab's screenshot for docs/: scaled to ``width`` and reduced to 128 colours."""
    if not SHOTS:
        return
    from PIL import Image

    img = Image.open(io.BytesIO(png)).convert("RGB")
    img = img.resize((width, round(img.height * width / img.width)), Image.LANCZOS)
    Path(SHOTS).mkdir(parents=True, exist_ok=True)
    img.quantize(128, dither=Image.Dither.NONE).save(Path(SHOTS) / name, optimize=True)


# --- processes -----------------------------------------------------------------------------------


def _start(cmd: list[str], env: dict | None = None, **kw) -> subprocess.Popen:
    return subprocess.Popen(cmd, env=env, start_new_session=True, **kw)


def _stop(proc: subprocess.Popen) -> None:
    stop_group(proc)


def _private_env(tmp_path: Path) -> dict:
    return dict(os.environ, XDG_DATA_HOME=str(tmp_path / "xdg"), RUST_LOG="warn")


def _wait(cond, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out waiting for {what}")
        time.sleep(0.3)


# --- native viewer -------------------------------------------------------------------------------


def _no_renderer(log: Path) -> str | None:
    text = log.read_text(errors="replace") if log.exists() else ""
    return next((line.strip() for line in text.splitlines()
                 if any(s in line for s in NO_RENDERER)), None)


@contextlib.contextmanager
def headless_viewer(tmp_path: Path):
    """A headless native viewer on loopback, its client; skipped (failed in CI) when the viewer
    finds no renderer after all (the ``native_viewer`` fixture found a driver)."""
    from rerun.experimental import ViewerClient

    port, log = free_port(), tmp_path / "viewer.log"
    proc = _start([str(RERUN), "--headless", "--bind", "127.0.0.1", "--port", str(port),
                   "--window-size", f"{WIDTH}x{HEIGHT}", "--hide-welcome-screen"],
                  env=_private_env(tmp_path), stdout=subprocess.DEVNULL,
                  stderr=open(log, "w"))  # noqa: SIM115
    try:
        deadline = time.monotonic() + 30
        while True:
            try:
                client = ViewerClient.connect(f"rerun+http://127.0.0.1:{port}/proxy")
                client.take_screenshot()  # the first frame: a renderer, or its absence
                break
            except Exception:
                if proc.poll() is not None or time.monotonic() > deadline:
                    time.sleep(0.5)  # the panic message is the last thing written
                    reason = _no_renderer(log)
                    if reason:
                        need(f"the viewer found no renderer ({reason}): "
                             "install mesa-vulkan-drivers")
                    pytest.fail(f"the headless viewer did not start: "
                                f"{log.read_text(errors='replace')[-1500:]}")
                time.sleep(0.5)
        yield client
    finally:
        _stop(proc)


def _tabs(layout: dict) -> list[tuple[str, str, list[tuple[str, str, str]]]]:
    """(tab id, tab name, [(view id, class, name)]) of the stored layout's tabs."""
    def entry(ref: str) -> dict:
        return layout.get("/" + ref, {})

    def views(ref: str) -> list[tuple[str, str, str]]:
        e = entry(ref)
        if "ViewBlueprint" in e:
            v = e["ViewBlueprint"]
            return [(ref.split("/")[-1], v["class_identifier"], v.get("display_name", ""))]
        return [w for child in e.get("ContainerBlueprint", {}).get("contents", [])
                for w in views(child)]

    tabs = next(v["ContainerBlueprint"] for v in layout.values()
                if v.get("ContainerBlueprint", {}).get("container_kind") == "Tabs")
    out = []
    for ref in tabs["contents"]:
        e = entry(ref)
        name = (e.get("ContainerBlueprint") or e.get("ViewBlueprint") or {}).get("display_name")
        out.append((ref, str(name), views(ref)))
    return out


MISSED: list[str] = []  # views asked for before they were drawn (the viewer shows a notice)


def _shot(client, view_id: str | None = None) -> bytes:
    for _ in range(40):  # right after a layout change a view may not exist for a moment
        try:
            return client.take_screenshot(view_id)
        except ConnectionError as e:
            if "not found" not in str(e):
                raise
            MISSED.append(str(view_id))
            time.sleep(0.25)
    raise AssertionError(f"view {view_id} never appeared")


def _show_tab(client, bp, ref: str) -> None:
    layout = json.loads(json.dumps(bp.blueprint))
    tabs = next(k for k, v in layout.items()
                if v.get("ContainerBlueprint", {}).get("container_kind") == "Tabs")
    layout[tabs]["ContainerBlueprint"]["active_tab"] = ref
    client.set_blueprint(layout, store_id=bp.store_id)


def _ids(ids) -> set[str]:
    return {str(i).replace("-", "") for i in ids}


def _tab_until_drawn(client, views: list, timeout: float = 30.0) -> tuple[bytes, dict]:
    """The tab's screenshot and each view's share of drawn pixels, once every view has drawn
    (a plot shows a loading mark for its first frames) or the time is up."""
    time.sleep(1.0)  # the new tab's first frame: asking a view not yet drawn for its
    deadline = time.monotonic() + timeout
    with ThreadPoolExecutor(len(views)) as pool:
        while True:  # the views together: the viewer answers all of them from one frame
            pngs = list(pool.map(lambda v: _shot(client, v[0]), views))
            shares = {v: drawn(_image(png), v[1]) for v, png in zip(views, pngs)}
            if all(s >= MIN_DRAWN.get(v[1], 0.002) for v, s in shares.items()) or (
                    time.monotonic() > deadline):
                if MISSED:  # the notice fades: keep it out of the tab's picture
                    MISSED.clear()
                    time.sleep(8.0)
                return _shot(client), shares
            time.sleep(0.5)


@pytest.mark.parametrize("which", ["sample", "counts"])
def test_native_viewer_every_panel_of_every_tab_draws_data(native_viewer, which, recordings,
                                                           tmp_path):
    """Each tab of the stored layout, as it opens (on ``time``, at the start): every panel
    has drawn data, and no view reports an error. One viewer process per recording."""
    with headless_viewer(tmp_path) as client:
        client.open([str(recordings[which])])
        _wait(lambda: not client.get_state().loading, 30, "the recording to load")
        bp = client.get_blueprint()
        tabs = _tabs(bp.blueprint)
        assert [name for _, name, _ in tabs] == ["Overview", "Signals", "Gravity", "L-curve",
                                                 "Optimiser", "Summary"]
        blank, errors = [], []
        for i, (ref, name, views) in enumerate(tabs):
            if i:
                _show_tab(client, bp, ref)
            png, shares = _tab_until_drawn(client, views)
            blank += [(name, v[2], round(s, 5)) for v, s in shares.items()
                      if s < MIN_DRAWN.get(v[1], 0.002)]
            errors += [(name, v.name, r.summary) for v in client.get_state().views
                       if v.visible for r in v.reports if r.severity.lower() == "error"]
            if which == "sample":
                _keep(f"tab-{i}-{name.lower()}.png", png)
        # Every view of the layout was one of a tab's (none missed by reading the layout).
        assert _ids(v.view_id for v in client.get_state().views) == _ids(
            v[0] for _, _, views in tabs for v in views)
        assert not blank, f"panels without data: {blank}"
        assert not errors, errors
        assert sum(len(v) for _, _, v in tabs) >= 25


# --- web viewer ----------------------------------------------------------------------------------


def _http_ok(url: str) -> bool:
    try:
        with urllib.request.urlopen(url, timeout=2) as r:
            return r.status == 200
    except OSError:
        return False


def tab_centres(img: np.ndarray, top: int = 36, bottom: int = 64) -> list[tuple[int, int]]:
    """The tab bar's labels (icon and name, apart from the next by a gap), as click points:
    pixels unlike the bar's background in the band where the tab bar is drawn."""
    band = img[top:bottom, : img.shape[1] // 2]
    background = np.median(band.reshape(-1, 3), axis=0)
    ink = (np.abs(band - background).max(axis=-1) > 60).any(axis=0)
    xs = np.flatnonzero(ink)
    if len(xs) == 0:
        return []
    groups = np.split(xs, np.flatnonzero(np.diff(xs) > 12) + 1)
    rows = np.flatnonzero((np.abs(band - background).max(axis=-1) > 60).any(axis=1))
    y = top + int(rows.mean()) if len(rows) else (top + bottom) // 2
    return [(int(g.mean()), y) for g in groups if g[-1] - g[0] > 20]


def test_web_viewer_clicks_through_every_tab_in_chromium(chromium_path, recordings, tmp_path):
    web_port = free_port()
    server = _start([sys.executable, "-c", "from imucal.cli import view_main; view_main()",
                     str(recordings["sample"]), "--web", "--port", str(web_port)],
                    env=_private_env(tmp_path), stdout=subprocess.PIPE,
                    stderr=open(tmp_path / "server.log", "w"), text=True)  # noqa: SIM115
    chrome = None
    try:
        lines: list[str] = []
        match = None
        while match is None and len(lines) < 20:  # the URL the launcher prints, first or soon
            lines.append(server.stdout.readline())
            if not lines[-1]:
                break
            match = re.search(r"http://127\.0\.0\.1:\d+/\S*", lines[-1])
        assert match, f"no URL in {lines!r}"
        _wait(lambda: _http_ok(f"http://127.0.0.1:{web_port}/"), 30, "the web viewer's server")
        chrome = DevTools(chromium_path, tmp_path / "profile", tmp_path / "chromium.log",
                          WIDTH, HEIGHT)
        chrome.open(match.group(0))

        def content() -> np.ndarray:  # below the tab bar, above the time panel
            return _image(chrome.screenshot())[70:HEIGHT - 40]

        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:  # until the plots show the data, not the layout
            if _colourful(content()).mean() > 0.01:
                break
            time.sleep(2)
        first = _image(chrome.screenshot())
        tabs = tab_centres(first)
        assert len(tabs) == 6, f"found {len(tabs)} tabs in the tab bar"
        seen = [content()]
        for i, (x, y) in enumerate(tabs[1:], start=1):
            deadline = time.monotonic() + 30
            clicked = 0.0
            while True:  # until the tab shows something else than the last, with data
                if time.monotonic() > clicked + 6:  # (again, if a click was lost)
                    chrome.click(x, y)
                    clicked = time.monotonic()
                time.sleep(1.5)
                img = content()
                changed = (np.abs(img - seen[-1]).max(axis=-1) > 40).mean()
                data = (img.max(axis=-1) > 150).mean() if i == len(tabs) - 1 else (
                    _colourful(img).mean())
                if (changed > 0.05 and data > 0.005) or time.monotonic() > deadline:
                    break
            assert changed > 0.05, f"tab {i} looks like tab {i - 1}"
            assert data > 0.005, f"tab {i} shows no data ({data:.4f})"
            seen.append(img)
    finally:
        if chrome is not None:
            chrome.close()
        _stop(server)
