"""The affine rate model ``w = M (w_raw - b)`` (method.md M4) on component arrays, for several
models at once."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from imucal.numerics.rk4.hamilton import Vec


def calibrator(models: list[tuple]) -> Callable[[Vec], Vec]:
    """M4 on component arrays for k models at once: ``w_i = sum_j M_ij (w_raw_j - b_j)``.

    Raw slabs are (rows, 1, K); the result (rows, k, K). Per element the arithmetic is the
    same as for one model, in the same order."""
    M = np.array([np.asarray(m, float) for m, _ in models])  # (k, 3, 3)
    b = np.array([np.asarray(bb, float) for _, bb in models])  # (k, 3)
    same_bias = bool(np.all(b == b[:1]))
    coef = [[M[:, i, j][None, :, None] for j in range(3)] for i in range(3)]
    if same_bias:
        b0 = b[0].tolist()
    else:
        bias = [b[:, j][None, :, None] for j in range(3)]

    def apply(w: Vec) -> Vec:
        if same_bias:
            d = [w[j] - b0[j] for j in range(3)]
        else:
            d = [w[j] - bias[j] for j in range(3)]
        out = []
        for i in range(3):
            o = d[0] * coef[i][0]
            o += d[1] * coef[i][1]
            o += d[2] * coef[i][2]
            out.append(o)
        return tuple(out)

    return apply
