"""The ordered product ``P[0] (x) P[1] (x) ... (x) P[L-1]`` of many step quaternions, reduced
pairwise in ``log2(L)`` vector operations for all columns at once.

Renormalising after every RK4 step equals normalising the product once at the end, because
``|q (x) P| = |q| |P|``: so a whole interval's rotation is the ordered product of its steps.
"""

from __future__ import annotations

import numpy as np

from imucal.numerics.rk4.hamilton import Quat, mul, mul_stacked

# Below this many elements per component, products go through one matrix product on stacked
# arrays (3 numpy calls instead of 28): small arrays are bound by per-call overhead. Kept
# under OpenBLAS's threading threshold for this (4 x 16) @ (16 x N) product, so that it never
# wakes a helper thread (which would then spin on the second core).
SMALL = 2048


def product_rows(P: Quat) -> Quat:
    """``P[0] (x) P[1] (x) ...`` along axis 0 of (L, ...) component arrays, pairwise.

    Each level multiplies rows ``2i`` and ``2i+1`` (strided views whose rows are contiguous);
    an odd last row is folded into the last product. Once the arrays are small the four
    components are stacked and each product is one matrix product. Not normalised.
    """
    while P[0].shape[0] > 1 and P[0].size > SMALL:
        n = P[0].shape[0]
        m = n - (n % 2)
        R = mul(tuple(c[0:m:2] for c in P), tuple(c[1:m:2] for c in P))
        if n % 2:
            k = m // 2
            last = mul(tuple(c[k - 1:k] for c in R), tuple(c[n - 1:n] for c in P))
            for c, v in zip(R, last):
                c[k - 1:k] = v
        P = R
    if P[0].shape[0] == 1:
        return tuple(c[0] for c in P)
    S = np.stack(P)  # (4, n, ...)
    while S.shape[1] > 1:
        n = S.shape[1]
        m = n - (n % 2)
        R = mul_stacked(S[:, 0:m:2], S[:, 1:m:2])
        if n % 2:
            k = m // 2
            R[:, k - 1:k] = mul_stacked(R[:, k - 1:k], S[:, n - 1:n])
        S = R
    return tuple(S[:, 0])


def ordered_product_soa(P: Quat) -> Quat:
    """``P[..., 0] (x) P[..., 1] (x) ...`` along the last axis, as a normalised (..., 4) array.

    Products of unit quaternions stay unit to rounding, so only the result is renormalised.
    """
    P = tuple(np.moveaxis(np.asarray(x, float), -1, 0) for x in P)
    out = np.stack(product_rows(P), axis=-1)
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def ordered_product(P: np.ndarray) -> np.ndarray:
    """Ordered product of (..., L, 4) quaternions along axis -2."""
    return ordered_product_soa(tuple(np.moveaxis(P, -1, 0)))
