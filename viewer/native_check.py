"""Will the native viewer's window draw here? The one case known to stay black, found before
the window opens.

Rerun 0.41 draws its own title bar on Linux and so always asks winit for a *transparent*
window, which on X11 means a 32-bit (ARGB) visual whenever the X server offers one (it does
when it has the Composite extension: every desktop's X server, and Xvfb's by default). Mesa's
software Vulkan renderer (lavapipe, what a machine without a GPU renders with) presents nothing
into such a window: it opens, stays black and says nothing (measured with Mesa 22.3 under Xvfb,
with and without a compositing manager; the same X server without the 32-bit visual,
``Xvfb -extension Composite``, shows every tab). Rerun has no option for an opaque window, and
its OpenGL renderer (``--renderer gl``) stops on llvmpipe ("Adapter does not support drawing to
texture format R32Float"), so where both conditions hold the viewer is not started and the user
is told so in one line, pointing to ``--web``. ``IMUCAL_NATIVE_VIEWER=1`` starts it anyway (a
newer Mesa may draw it).

Everything here reads the machine only (device nodes, the X server's visuals through libX11),
never the recording.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import glob
import os
from collections.abc import Mapping

FORCE_ENV = "IMUCAL_NATIVE_VIEWER"  # "1": start the native viewer whatever is found here
TRUE_COLOR = 4  # X11's TrueColor visual class


class _XVisualInfo(ctypes.Structure):
    _fields_ = [("visual", ctypes.c_void_p), ("visualid", ctypes.c_ulong),
                ("screen", ctypes.c_int), ("depth", ctypes.c_int), ("c_class", ctypes.c_int),
                ("red_mask", ctypes.c_ulong), ("green_mask", ctypes.c_ulong),
                ("blue_mask", ctypes.c_ulong), ("colormap_size", ctypes.c_int),
                ("bits_per_rgb", ctypes.c_int)]


def x_argb_visual(display: str) -> bool | None:
    """True when the X server at ``display`` offers a 32-bit TrueColor visual (the one winit
    takes for a transparent window), False when it does not, None when it cannot be asked (no
    libX11, the server does not answer)."""
    name = ctypes.util.find_library("X11")
    if name is None:
        return None
    try:
        x11 = ctypes.CDLL(name)
    except OSError:
        return None
    x11.XOpenDisplay.restype = ctypes.c_void_p
    x11.XOpenDisplay.argtypes = [ctypes.c_char_p]
    x11.XDefaultScreen.argtypes = [ctypes.c_void_p]
    x11.XMatchVisualInfo.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_int, ctypes.c_int,
                                     ctypes.POINTER(_XVisualInfo)]
    x11.XCloseDisplay.argtypes = [ctypes.c_void_p]
    dpy = x11.XOpenDisplay(display.encode())
    if not dpy:
        return None
    try:
        info = _XVisualInfo()
        return bool(x11.XMatchVisualInfo(dpy, x11.XDefaultScreen(dpy), 32, TRUE_COLOR,
                                         ctypes.byref(info)))
    finally:
        x11.XCloseDisplay(dpy)


def software_vulkan_only(env: Mapping[str, str]) -> bool:
    """True when Vulkan can only render in software here: no GPU render node
    (``/dev/dri/renderD*``), or the Vulkan loader told to use lavapipe alone
    (``VK_DRIVER_FILES`` / ``VK_ICD_FILENAMES``)."""
    override = env.get("VK_DRIVER_FILES") or env.get("VK_ICD_FILENAMES")
    if override:
        names = [os.path.basename(p) for p in override.split(os.pathsep) if p]
        if names and all("lvp" in n for n in names):
            return True
    return not glob.glob("/dev/dri/renderD*")


def black_window_reason(env: Mapping[str, str]) -> str | None:
    """Why the native viewer's window would stay black on this display (one line, pointing to
    ``--web``), or None when nothing known stops it drawing.

    Only X11 is concerned (on Wayland winit does not pick a visual); the check is skipped when
    ``IMUCAL_NATIVE_VIEWER=1`` or when the X server cannot be asked."""
    if env.get(FORCE_ENV, "").strip() not in ("", "0"):
        return None
    display = env.get("DISPLAY")
    if not display or env.get("WAYLAND_DISPLAY") or env.get("WGPU_BACKEND", "").lower() == "gl":
        return None
    if not software_vulkan_only(env):
        return None
    with contextlib.suppress(Exception):  # libX11 misbehaving must not stop the viewer
        if x_argb_visual(display):
            return ("the native viewer's window would stay black here: with no GPU, Mesa's "
                    "software Vulkan renderer does not draw the transparent 32-bit window rerun "
                    f"opens on this X display ({display}); use --web (or an X server without "
                    f"its Composite extension; {FORCE_ENV}=1 opens it anyway)")
    return None
