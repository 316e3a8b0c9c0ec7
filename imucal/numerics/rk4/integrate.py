"""The rotation over every interval of every bucket, under several rate models at once: RK4
steps (:mod:`.step`) reduced by ordered products (:mod:`.product`), a slab of rows at a time so
that the temporaries stay in cache (method.md M5)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from imucal.numerics.rk4.affine import calibrator
from imucal.numerics.rk4.buckets import Bucket
from imucal.numerics.rk4.hamilton import Vec, mul
from imucal.numerics.rk4.product import product_rows
from imucal.numerics.rk4.step import rk4_raw

# Elements (rows x intervals) evaluated at once: large enough that numpy's per-call overhead
# is small, small enough that the ~20 live temporaries stay in cache (measured in bench/).
SLAB = 32768


def integrate_buckets(buckets: list[Bucket], n: int, samples: list[Vec],
                      models: list[tuple] | Callable[[Vec], Vec] | None = None) -> np.ndarray:
    """Quaternions (k, n, 4), normalised, of the ``n`` intervals of ``buckets`` under each of k
    models.

    ``samples`` are the raw rates of each bucket ((L + 1, K_b) per component); ``models`` a
    list of ``(M, b)``, the calibrated rate being ``M (w - b)`` (M4), or ``None`` for the rates
    as they are (k = 1), or a function calibrating a raw slab ((rows, 1, K_b) per component,
    k = 1). Slab by slab of rows, each model's arithmetic is the same as alone.
    """
    k = 1 if models is None or callable(models) else len(models)
    out = np.empty((k, n, 4))
    out[:] = (1.0, 0.0, 0.0, 0.0)
    cal = models if models is None or callable(models) else calibrator(models)
    for (idx, _, _, dt, dt2), w in zip(buckets, samples):
        L, kb = dt.shape
        # Slabs depend on the layout only, not on k: the reduction tree, and so the
        # rounding, is the same for a model alone and among several.
        rows = max(1, SLAB // max(kb, 1))
        acc = None
        for r0 in range(0, L, rows):
            r1 = min(r0 + rows, L)
            c = tuple(x[r0:r1 + 1][:, None, :] for x in w)  # a lazy bucket gathers here
            if cal is not None:
                c = cal(c)
            a = tuple(x[:-1] for x in c)
            b = tuple(x[1:] for x in c)
            q = product_rows(rk4_raw(a, b, dt[r0:r1][:, None, :], dt2[r0:r1][:, None, :]))
            acc = q if acc is None else mul(acc, q)
        out[:, idx] = np.stack(np.broadcast_arrays(*acc), axis=-1)
    return out / np.linalg.norm(out, axis=-1, keepdims=True)
