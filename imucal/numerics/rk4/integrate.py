"""The rotation over every interval of every bucket, under several rate models at once: RK4
steps (:mod:`.step`) reduced by ordered products (:mod:`.product`), a slab of rows at a time so
that the temporaries stay in cache (method.md M5)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from imucal.numerics.rk4.affine import calibrator
from imucal.numerics.rk4.buckets import Bucket
from imucal.numerics.rk4.hamilton import Quat, Vec, mul
from imucal.numerics.rk4.lazy import SLAB, slab_ranges, slab_rows
from imucal.numerics.rk4.product import product_rows
from imucal.numerics.rk4.step import rk4_raw

__all__ = ["SLAB", "integrate_buckets", "slab_steps"]


def slab_steps(w: Vec, dt: np.ndarray, dt2: np.ndarray, cal: Callable[[Vec], Vec] | None
               ) -> Quat:
    """The unnormalised RK4 steps (:func:`~.step.rk4_raw`) of a slab: raw samples ``w``
    ((m + 1, K_b) per component) calibrated by ``cal`` ((rows, 1, K_b) per component in,
    (rows, k, K_b) out; None: as they are), steps ``dt``, ``dt2`` (m, K_b); (m, k, K_b)."""
    c = tuple(x[:, None, :] for x in w)
    if cal is not None:
        c = cal(c)
    return rk4_raw(tuple(x[:-1] for x in c), tuple(x[1:] for x in c), dt[:, None, :],
                   dt2[:, None, :])


def integrate_buckets(buckets: list[Bucket], n: int, samples: list,
                      models: list[tuple] | Callable[[Vec], Vec] | None = None) -> np.ndarray:
    """Quaternions (k, n, 4), normalised, of the ``n`` intervals of ``buckets`` under each of k
    models.

    ``samples`` are the raw rates of each bucket ((L + 1, K_b) per component, or a
    :class:`~.lazy.LazyRows`); ``models`` a list of ``(M, b)``, the calibrated rate being
    ``M (w - b)`` (M4), or ``None`` for the rates as they are (k = 1), or a function
    calibrating a raw slab ((rows, 1, K_b) per component, k = 1). Slab by slab of rows, each
    model's arithmetic is the same as alone.
    """
    k = 1 if models is None or callable(models) else len(models)
    out = np.empty((k, n, 4))
    out[:] = (1.0, 0.0, 0.0, 0.0)
    cal = models if models is None or callable(models) else calibrator(models)
    for bucket, w in zip(buckets, samples):
        src = slab_rows(bucket, w)
        acc = None
        for r0, r1 in slab_ranges(*bucket.dt.shape):
            w_slab, dt, dt2, _ = src.slab(r0, r1)
            q = product_rows(slab_steps(w_slab, dt, dt2, cal))
            del w_slab, dt, dt2  # views of the block read: let it go when the next is read
            acc = q if acc is None else mul(acc, q)
        out[:, bucket.idx] = np.stack(np.broadcast_arrays(*acc), axis=-1)
    return out / np.linalg.norm(out, axis=-1, keepdims=True)
