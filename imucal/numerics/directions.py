"""How many distinct directions a set of vectors points in."""

from __future__ import annotations

import numpy as np

# Two still poses this far apart are distinct orientations; a turn that moves gravity less
# lands in the same pose (imucal.stages.guide.MIN_TILT_DEG, the warnings, the viewer).
DISTINCT_ANGLE_DEG = 15.0


def distinct_orientations(vectors: np.ndarray, min_angle_deg: float = DISTINCT_ANGLE_DEG) -> int:
    """How many of the directions differ from all kept ones by at least ``min_angle_deg``.

    A greedy count over blocks (tens to hundreds), not over samples.
    """
    if len(vectors) == 0:
        return 0
    u = vectors / np.linalg.norm(vectors, axis=1, keepdims=True)
    cos_min = np.cos(np.radians(min_angle_deg))
    kept: list[np.ndarray] = []
    for v in u:
        if not kept or np.max(np.array(kept) @ v) < cos_min:
            kept.append(v)
    return len(kept)
