"""The sizes of the 2D plots (:mod:`viewer.plot2d`), shared by the modules that draw them and
the blueprint that frames them: a 2D view has no axes of its own, so a plot is drawn in scene
units of about a pixel at the default window (1600x1000), where labels, which keep their pixel
size, have been given room. Measured in the headless viewer at that size: a view's drawing
area, below its title bar."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Box:
    """A plot's data area (``width`` x ``height`` scene units, y down) and the margins around
    it for tick labels (left, bottom) and the series' names (right)."""

    width: float
    height: float
    left: float = 84.0
    right: float = 150.0
    top: float = 14.0
    bottom: float = 30.0

    def bounds(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """The view's visual bounds: ``(x_range, y_range)``."""
        return ((-self.left, self.width + self.right), (-self.top, self.height + self.bottom))

    @classmethod
    def fitting(cls, view_w: float, view_h: float, **margins: float) -> Box:
        """The box whose bounds fill a view of ``view_w`` x ``view_h`` pixels."""
        b = cls(1.0, 1.0, **margins)
        return cls(view_w - b.left - b.right, view_h - b.top - b.bottom, **margins)


# L-curve tab: the L-curve on the left half, four plots against lambda on the right.
LCURVE_BOX = Box.fitting(794, 872, left=70, right=130, top=30, bottom=58)
# The Magnetometer tab's small L-curve (M8r), under its note
MAG_LCURVE_BOX = Box.fitting(400, 330, left=70, right=30, top=30, bottom=58)
SWEEP_BOX = Box.fitting(793, 192)
# Optimiser tab: four plots per sensor, one column per sensor (the whole width without one).
TRACE_BOX = Box.fitting(793, 192)
TRACE_BOX_WIDE = Box.fitting(1593, 192)
# Overview: the evidence plots (:mod:`viewer.evidence`), stacked in the left column (3/7 of
# the width) with the accelerometer's magnitude, over the lanes.
EVIDENCE_BOX = Box.fitting(683, 226, left=60, right=80, top=14, bottom=30)
