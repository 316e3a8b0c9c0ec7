"""The Gravity tab's entities: per segment, block k's measured gravity at its first sample; for
k > 0 also the one carried over from block k-1 by the raw and the calibrated gyroscope (M5),
and the angles between them. Every array is a :class:`~imucal.stages.gyro.GyroFit`'s own."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import rerun as rr

from . import paths as P
from .columns import AFTER, BEFORE, MEASURED, PREVIOUS, XYZ, rgba, send_scalars, style_points

if TYPE_CHECKING:
    from imucal.result import Result

# Drawn lengths of the predicted gravity arrows (the measured one: 1). The predictions nearly
# coincide with the measured direction: drawn longer and thinner, their tips stay visible.
ARROW_AFTER = 1.12
ARROW_BEFORE = 1.24


def log_gravity(result: Result, rec: rr.RecordingStream, rows: dict[str, int]) -> None:
    segs = [s for s in result.segments if s.gyro is not None and len(s.gyro.u_meas)]
    if not segs:
        return
    starts = result.block_times[:, 0]
    t_meas = np.concatenate([starts[s.blocks[0]:s.blocks[1]] for s in segs])
    t = np.concatenate([starts[s.blocks[0] + 1:s.blocks[1]] for s in segs])
    fits = [s.gyro for s in segs]
    # path: (times, unit vectors, drawn length, colour, radius)
    arrows = {
        P.GRAVITY_MEASURED: (t_meas, np.concatenate([f.u_blocks for f in fits]), 1.0, MEASURED,
                             0.025),
        P.GRAVITY_PREVIOUS: (t, np.concatenate([f.u_prev for f in fits]), 1.0, PREVIOUS, 0.015),
        P.GRAVITY_PREDICTED_AFTER: (t, np.concatenate([f.u_pred_after for f in fits]),
                                    ARROW_AFTER, AFTER, 0.012),
    }
    have_before = all(f.u_pred_before is not None for f in fits)
    if have_before:
        arrows[P.GRAVITY_PREDICTED_BEFORE] = (
            t, np.concatenate([f.u_pred_before for f in fits]), ARROW_BEFORE, BEFORE, 0.012)
    rec.log(P.GRAVITY_AXES, rr.Arrows3D(vectors=np.eye(3) * 1.2, colors=rgba(XYZ),
                                        labels=["x", "y", "z"], radii=0.006), static=True)
    for path, (tt, v, length, color, radius) in arrows.items():
        n = len(tt)
        rec.send_columns(path, indexes=[rr.TimeColumn(P.TIME, duration=tt)],
                         columns=rr.Arrows3D.columns(vectors=v * length,
                                                     colors=rgba([color] * n),
                                                     radii=[radius] * n))
        rows[path] = n

    after = np.concatenate([f.angle_after for f in fits])
    rows[P.GRAVITY_ANGLE_AFTER] = send_scalars(rec, P.GRAVITY_ANGLE_AFTER, t, after)
    style_points(rec, P.GRAVITY_ANGLE_AFTER, ["after: calibrated gyro (deg)"], [AFTER])
    if have_before:
        before = np.concatenate([f.angle_before for f in fits])
        rows[P.GRAVITY_ANGLE_BEFORE] = send_scalars(rec, P.GRAVITY_ANGLE_BEFORE, t, before)
        style_points(rec, P.GRAVITY_ANGLE_BEFORE, ["before: raw gyro (deg)"], [BEFORE])
