"""Corner of the L-curve (thesis ch. 5): the point of maximum curvature of (log rho, log eta)."""

from __future__ import annotations

import numpy as np


def lcurve_corner(lambdas: np.ndarray, rho: np.ndarray, eta: np.ndarray) -> tuple[int, np.ndarray]:
    """Index of the corner and the signed curvature at every grid point.

    The curve is parametrised by ``log lambda`` (a uniform grid), so derivatives are central
    differences. Walking from small to large lambda the L turns from "down" (eta falling,
    rho flat) to "right" (rho rising): a counter-clockwise turn, i.e. positive curvature, so
    the corner is the maximum of the signed curvature. Points where the curve has not moved
    at all (floating-point flat) carry no direction and are excluded.
    """
    x = np.log(np.maximum(rho, 1e-300))
    y = np.log(np.maximum(eta, 1e-300))
    t = np.log(lambdas)
    if len(t) < 3:
        return int(np.argmin(lambdas)), np.zeros(len(t))
    dx, dy = np.gradient(x, t), np.gradient(y, t)
    ddx, ddy = np.gradient(dx, t), np.gradient(dy, t)
    speed2 = dx * dx + dy * dy
    with np.errstate(divide="ignore", invalid="ignore"):
        curv = (dx * ddy - ddx * dy) / speed2**1.5
    # A curve flat to rounding still moves by about eps |x| / h per unit of log lambda (the
    # grid is uniform only to rounding, so np.gradient of a constant is not exactly 0): below
    # a few hundred times that nothing moved, whatever the largest speed.
    h = np.max(np.abs(np.diff(t)))
    flat = (256 * np.finfo(float).eps * max(np.max(np.abs(x)), np.max(np.abs(y)), 1.0) / h) ** 2
    moving = speed2 > max(1e-6 * np.max(speed2), flat)
    curv = np.where(moving & np.isfinite(curv), curv, np.nan)
    curv[[0, -1]] = np.nan  # one-sided differences at the ends are not trusted
    if np.all(np.isnan(curv)) or np.nanmax(curv) <= 0:
        # No corner: the data fix every parameter whatever lambda is; take the smallest.
        return 0, np.nan_to_num(curv)
    return int(np.nanargmax(curv)), np.nan_to_num(curv)
