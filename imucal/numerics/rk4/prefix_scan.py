"""Every prefix ``P[0] (x) ... (x) P[n]`` of a sequence of step quaternions (the orientation at
every sample of an interval), by the work-efficient parallel scan: ``2 L`` products in
``log2(L)`` levels, each level one vector operation over all columns.
"""

from __future__ import annotations

import numpy as np

from imucal.numerics.rk4.hamilton import Quat, mul


def prefix_rows(P: Quat) -> Quat:
    """Inclusive prefix products ``P[0] (x) ... (x) P[n]`` along axis 0 of (L, ...) component
    arrays, for every ``n``, in ``2 L`` products and ``log2(L)`` levels.

    The rows are multiplied in pairs, the pairs' prefixes found recursively, and each even row
    then gets the prefix of the pairs before it (the work-efficient parallel scan).
    """
    n = P[0].shape[0]
    if n == 1:
        return tuple(c.copy() for c in P)
    m = n // 2
    pairs = prefix_rows(mul(tuple(c[0:2 * m:2] for c in P), tuple(c[1:2 * m:2] for c in P)))
    out = tuple(np.empty_like(c) for c in P)
    for o, c, s in zip(out, P, pairs):
        o[1:2 * m:2] = s  # row 2j + 1: the prefix of pairs 0..j
        o[0] = c[0]
    if n > 2:
        even = mul(tuple(s[0:(n - 1) // 2] for s in pairs), tuple(c[2:n:2] for c in P))
        for o, e in zip(out, even):
            o[2:n:2] = e  # row 2j: the prefix of pairs 0..j-1, times row 2j
    return out
