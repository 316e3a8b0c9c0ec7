"""The Overview's evidence that the calibration worked: each sensor's error before and after,
per still block and per turn, on log axes (2D plots, :mod:`viewer.plot2d`), so an error of 3
degrees and one of 0.04 both show (on a linear axis the "after" points lie on zero).

- the gyroscope: the rotation error of each turn, the angle between the gravity measured after
  the turn and the one carried over from before it by the integrated rate (method.md M5), with
  the raw gyroscope through its nominal scale (before) and calibrated (after):
  ``GyroFit.angle_before`` / ``angle_after``;
- the accelerometer: each still block's ``| |mean a| / g - 1 |`` in mg, raw (nominal frame)
  and calibrated: ``Quality.block_norm_error_before_mg`` / ``block_norm_error_mg`` (its size:
  a log axis has no sign; the Gravity tab shows the signed values).

x is the session's time (s) of the turn's end (the block after it) or of the block's middle.
Each series holds ``AnyValues`` ``t_s`` and ``deg`` / ``mg`` (signed): the core's numbers as
they are, for scripts (:mod:`viewer.readback`). A "before" series exists only where the core
has the raw figure (not for raw counts without a nominal scale).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import rerun as rr

from . import paths as P
from .columns import AFTER, BEFORE, log10_axis
from .layout import EVIDENCE_BOX
from .plot2d import Axis, Series, linear_axis, log_axis, log_plot

if TYPE_CHECKING:
    from imucal.result import Result


def turn_errors(result: Result) -> tuple[np.ndarray, np.ndarray | None, np.ndarray] | None:
    """(times s, before deg or None, after deg) of every turn with both gravities measured
    (each segment's block k > 0, at its first sample), or None without a gyroscope fit."""
    segs = [s for s in result.segments if s.gyro is not None and len(s.gyro.u_meas)]
    if not segs:
        return None
    starts = result.block_times[:, 0]
    t = np.concatenate([starts[s.blocks[0] + 1:s.blocks[1]] for s in segs])
    after = np.concatenate([s.gyro.angle_after for s in segs])
    before = None
    if all(s.gyro.angle_before is not None for s in segs):
        before = np.concatenate([s.gyro.angle_before for s in segs])
    return t, before, after


def _plot(rec: rr.RecordingStream, base: str, t: np.ndarray, before: np.ndarray | None,
          after: np.ndarray, unit: str) -> None:
    series = []
    ys = []
    for name, label, color, v in (("before", "before", BEFORE, before),
                                  ("after", "after", AFTER, after)):
        if v is None:
            continue
        y = log10_axis(np.abs(v))
        ys.append(y)
        series.append(Series(name, label, color, t, y, line=False, size=3.0,
                             values={"t_s": np.asarray(t, float), unit: np.asarray(v, float)}))
    xa = linear_axis(t, pad=0.03, most=4)
    xa = Axis(xa.lo, xa.hi, xa.ticks, [f"{label} s" for label in xa.labels])  # x has no title
    log_plot(rec, base, EVIDENCE_BOX, xa, log_axis(np.concatenate(ys), most=5), series)


def log_evidence(result: Result, rec: rr.RecordingStream) -> None:
    q = result.quality
    _plot(rec, P.EVIDENCE_BLOCKS, result.block_middles, q.block_norm_error_before_mg,
          q.block_norm_error_mg, "mg")
    turns = turn_errors(result)
    if turns is not None:
        _plot(rec, P.EVIDENCE_TURNS, *turns, "deg")


def evidence_titles(result: Result | None) -> tuple[str, str]:
    """The two plots' titles (turns, blocks): what is plotted and the RMS before and after
    (the core's ``Quality`` figures) where ``result`` is given; the legend names the colours."""
    def figures(ba, unit: str) -> str:
        if ba is None:
            return ""
        if ba.before is None:
            return f", RMS {ba.after:.3g} {unit}"
        return f", RMS {ba.before:.3g} before → {ba.after:.3g} after"

    q = None if result is None else result.quality
    turns = figures(None if q is None else q.gravity_angle_rms_deg, "deg")
    blocks = figures(None if q is None else q.static_norm_rms_mg, "mg")
    return (f"Gyroscope: rotation error per turn (deg, log){turns}",
            f"Accelerometer: |ā|/g − 1 per still block (mg, log){blocks}")
