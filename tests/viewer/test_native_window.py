"""The native viewer's real window, as a user sees it: ``imucal-view FILE.rrd`` under Xvfb with
the machine's Vulkan renderer (Mesa's software one where there is no GPU), screenshots of the
X server's screen itself, not the viewer's own headless rendering (which draws even where the
window stays black: tests/viewer/test_viewer_screens.py).

- An X server without the 32-bit visual (``Xvfb -extension Composite``): the window draws, and
  every tab (switched through the viewer's gRPC port, as a click would) shows data.
- An X server with it (Xvfb's default, every desktop's) on a machine without a GPU: rerun's
  transparent window stays black there, so ``imucal-view`` refuses in one line pointing to
  ``--web``; and the refusal is checked to be still needed (the window, opened anyway with
  ``IMUCAL_NATIVE_VIEWER=1``, is black).

Needs Xvfb (package ``xvfb``) and a Vulkan renderer (``mesa-vulkan-drivers``): skipped naming
the package where one is missing, failed in CI (``tests/viewer_env.py``). Every process started
here gets its own process group and is ended by its group id.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from test_viewer_screens import HEIGHT, WIDTH, _colourful, _show_tab, _tabs  # tests/viewer
from viewer_env import need, need_native_viewer, stop_group

import imucal
from viewer.app import free_port
from viewer.native_check import FORCE_ENV, software_vulkan_only, x_argb_visual
from viewer.recording import save_recording

pytestmark = pytest.mark.viewer

VIEW = [sys.executable, "-c", "from imucal.cli import view_main; view_main()"]
SHOTS = os.environ.get("IMUCAL_SCREENSHOT_DIR")


@pytest.fixture(scope="module")
def rrd(tmp_path_factory, sample_session_path) -> Path:
    path = tmp_path_factory.mktemp("window") / "session.rrd"
    save_recording(imucal.calibrate(imucal.load_session(sample_session_path)), path)
    return path


# --- the X server and its screen -----------------------------------------------------------------


def _xvfb(composite: bool, log: Path) -> tuple[subprocess.Popen, str]:
    """An Xvfb of the test window's size on a display number it picks itself (``-displayfd``)."""
    need_native_viewer()
    xvfb = shutil.which("Xvfb")
    need(None if xvfb else "no Xvfb to open the native viewer's window in: install xvfb")
    read, write = os.pipe()
    cmd = [str(xvfb), "-displayfd", str(write), "-screen", "0", f"{WIDTH}x{HEIGHT}x24",
           "-nolisten", "tcp"] + ([] if composite else ["-extension", "Composite"])
    proc = subprocess.Popen(cmd, pass_fds=(write,), start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=open(log, "w"))  # noqa: SIM115
    os.close(write)
    with os.fdopen(read) as f:
        number = f.readline().strip()
    if not number:
        stop_group(proc)
        pytest.fail(f"Xvfb did not start: {log.read_text(errors='replace')[-500:]}")
    return proc, f":{number}"


class XImage(ctypes.Structure):  # the head of Xlib's XImage, up to the fields read here
    _fields_ = [("width", ctypes.c_int), ("height", ctypes.c_int), ("xoffset", ctypes.c_int),
                ("format", ctypes.c_int), ("data", ctypes.POINTER(ctypes.c_ubyte)),
                ("byte_order", ctypes.c_int), ("bitmap_unit", ctypes.c_int),
                ("bitmap_bit_order", ctypes.c_int), ("bitmap_pad", ctypes.c_int),
                ("depth", ctypes.c_int), ("bytes_per_line", ctypes.c_int),
                ("bits_per_pixel", ctypes.c_int)]


def screen(display: str) -> np.ndarray:
    """The X server's whole screen, RGB (what is on it: the real window, as a user sees it)."""
    x11 = ctypes.CDLL(ctypes.util.find_library("X11"))
    x11.XOpenDisplay.restype = ctypes.c_void_p
    x11.XOpenDisplay.argtypes = [ctypes.c_char_p]
    x11.XDefaultRootWindow.restype = ctypes.c_ulong
    x11.XDefaultRootWindow.argtypes = [ctypes.c_void_p]
    x11.XGetImage.restype = ctypes.POINTER(XImage)
    x11.XGetImage.argtypes = [ctypes.c_void_p, ctypes.c_ulong, ctypes.c_int, ctypes.c_int,
                              ctypes.c_uint, ctypes.c_uint, ctypes.c_ulong, ctypes.c_int]
    x11.XFree.argtypes = [ctypes.c_void_p]
    x11.XCloseDisplay.argtypes = [ctypes.c_void_p]
    dpy = x11.XOpenDisplay(display.encode())
    assert dpy, f"cannot open X display {display}"
    try:
        img = x11.XGetImage(dpy, x11.XDefaultRootWindow(dpy), 0, 0, WIDTH, HEIGHT,
                            ctypes.c_ulong(-1).value, 2)  # AllPlanes, ZPixmap
        head = img.contents
        assert head.bits_per_pixel == 32, head.bits_per_pixel
        raw = np.ctypeslib.as_array(head.data, (head.height * head.bytes_per_line,)).copy()
        x11.XFree(ctypes.cast(head.data, ctypes.c_void_p))
        x11.XFree(ctypes.cast(img, ctypes.c_void_p))
    finally:
        x11.XCloseDisplay(dpy)
    bgrx = raw.reshape(HEIGHT, -1)[:, : WIDTH * 4].reshape(HEIGHT, WIDTH, 4)
    return bgrx[..., 2::-1].astype(np.int16)  # little-endian BGRX -> RGB


def _env(tmp_path: Path, display: str, **extra: str) -> dict[str, str]:
    home = tmp_path / "home"
    home.mkdir(exist_ok=True)
    env = dict(os.environ, DISPLAY=display, HOME=str(home),
               XDG_CONFIG_HOME=str(home / ".config"), XDG_DATA_HOME=str(home / ".local"),
               **extra)
    for name in ("WAYLAND_DISPLAY", FORCE_ENV):
        env.pop(name, None)
    env.update(extra)
    return env


def _keep(name: str, img: np.ndarray) -> None:
    if SHOTS:
        from PIL import Image

        Path(SHOTS).mkdir(parents=True, exist_ok=True)
        Image.fromarray(img.astype(np.uint8)).save(Path(SHOTS) / name, optimize=True)


# --- tests ---------------------------------------------------------------------------------------


def test_real_window_draws_every_tab_on_an_opaque_visual(rrd, tmp_path):
    """``imucal-view FILE.rrd`` on an X server without the 32-bit visual: the window is not
    black, and each tab, shown in turn, fills the window below the tab bar with data."""
    from rerun.experimental import ViewerClient

    xvfb, display = _xvfb(composite=False, log=tmp_path / "xvfb.log")
    viewer = None
    try:
        assert x_argb_visual(display) is False  # the X server's side of the condition
        grpc = free_port()
        viewer = subprocess.Popen([*VIEW, str(rrd), "--grpc-port", str(grpc)],
                                  env=_env(tmp_path, display), start_new_session=True,
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 60
        client = None
        while client is None:
            if viewer.poll() is not None:
                pytest.fail(f"imucal-view exited {viewer.returncode}: {viewer.stderr.read()}")
            try:
                client = ViewerClient.connect(f"rerun+http://127.0.0.1:{grpc}/proxy")
                while client.get_state().loading:
                    time.sleep(0.3)
            except Exception:
                client = None
                assert time.monotonic() < deadline, "the native viewer never answered"
                time.sleep(0.5)
        bp = None
        while bp is None:  # the recording may not have arrived when the viewer first answers
            try:
                bp = client.get_blueprint()
            except ConnectionError:
                assert time.monotonic() < deadline, "the recording never opened"
                time.sleep(0.5)
        tabs = _tabs(bp.blueprint)
        assert len(tabs) == 6
        previous = None
        for i, (ref, name, _) in enumerate(tabs):
            if i:
                _show_tab(client, bp, ref)
            deadline = time.monotonic() + 40
            while True:  # until the tab has drawn its data (a plot's first frames are empty)
                time.sleep(1.0)
                img = screen(display)
                content = img[70:HEIGHT - 40]  # below the tab bar, above the time panel
                lit = float((content.max(axis=-1) > 0).mean())
                data = float((content.max(axis=-1) > 150).mean()) if name == "Summary" else (
                    float(_colourful(content).mean()))
                changed = 1.0 if previous is None else float(
                    (np.abs(content - previous).max(axis=-1) > 40).mean())
                if (data > 0.005 and changed > 0.05) or time.monotonic() > deadline:
                    break
            assert img.std() > 10, f"tab {name}: the window is uniform (std {img.std():.1f})"
            assert lit > 0.5, f"tab {name}: only {lit:.1%} of the window is not black"
            assert data > 0.005, f"tab {name}: no data drawn ({data:.4f})"
            assert changed > 0.05, f"tab {name} looks like the tab before it"
            _keep(f"window-{i}-{name.lower()}.png", img)
            previous = content
    finally:
        if viewer is not None:
            stop_group(viewer)
        stop_group(xvfb)


def test_black_window_is_refused_in_one_line_and_is_really_black(rrd, tmp_path):
    """On an X server with the 32-bit visual and no GPU: one line naming --web, exit 1, at once;
    opened anyway (``IMUCAL_NATIVE_VIEWER=1``), the window is black: the refusal is needed."""
    xvfb, display = _xvfb(composite=True, log=tmp_path / "xvfb.log")
    viewer = None
    try:
        env = _env(tmp_path, display)
        if not software_vulkan_only(env):
            pytest.skip("a GPU is present: the software renderer's black window cannot happen")
        assert x_argb_visual(display) is True
        t0 = time.monotonic()
        done = subprocess.run([*VIEW, str(rrd)], env=env, capture_output=True, text=True,
                              timeout=60)
        assert done.returncode == 1
        assert done.stdout == "" and len(done.stderr.strip().splitlines()) == 1, done.stderr
        assert "would stay black" in done.stderr and "--web" in done.stderr
        assert time.monotonic() - t0 < 20  # before any window or calibration

        viewer = subprocess.Popen([*VIEW, str(rrd)], env=_env(tmp_path, display,
                                                              **{FORCE_ENV: "1"}),
                                  start_new_session=True, stdout=subprocess.DEVNULL,
                                  stderr=subprocess.DEVNULL)
        time.sleep(20)  # the open window's time to draw (the other test's draws in ~10 s)
        assert viewer.poll() is None, "the viewer opened anyway stopped"
        img = screen(display)
        assert img.max() == 0, ("Mesa's software renderer now draws rerun's transparent "
                                "window: viewer/native_check.py's refusal can go")
    finally:
        if viewer is not None:
            stop_group(viewer)
        stop_group(xvfb)
