"""Every prefix ``P[0] (x) ... (x) P[n]`` of a sequence of step quaternions (the orientation at
every sample of an interval), by the work-efficient parallel scan: ``2 L`` products in
``log2(L)`` levels, each level one vector operation over all columns.
"""

from __future__ import annotations

import numpy as np

from imucal.numerics.rk4.hamilton import Quat, mul
from imucal.numerics.rk4.product import SMALL, product_rows


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
    return _down_sweep(P, pairs)


def prefix_and_product(P: Quat) -> tuple[Quat, Quat]:
    """:func:`prefix_rows` and :func:`~.product.product_rows` of the same (L, ...) rows, each
    the same to the bit as alone, from one up-sweep.

    Both first multiply rows ``2i`` and ``2i+1``, then the pairs' rows ``2i`` and ``2i+1``, and
    so on: the product's tree is the scan's up-sweep, except that the product folds an odd last
    row into the last pair of its level. So the two part in one row a level only (carried as
    ``last``, :func:`_up_sweep`), and the product costs ``log2(L)`` one-row products instead
    of ``L`` products."""
    return _up_sweep(P, None)


def _up_sweep(P: Quat, last: Quat | None) -> tuple[Quat, Quat]:
    """:func:`prefix_rows` of ``P`` and :func:`~.product.product_rows` of ``P`` with its last
    row replaced by ``last`` (one row, (1, ...); None: ``P`` as it is)."""
    n = P[0].shape[0]
    if n == 1:
        return tuple(c.copy() for c in P), tuple(c[0] for c in (P if last is None else last))
    if P[0].size <= SMALL:  # the product goes on by stacked matrix products: its own rows
        rows = P if last is None else tuple(np.concatenate([c[:-1], v]) for c, v in zip(P, last))
        return prefix_rows(P), product_rows(rows)
    m = n // 2
    pairs = mul(tuple(c[0:2 * m:2] for c in P), tuple(c[1:2 * m:2] for c in P))
    if n % 2:  # the product folds the last row into its last pair
        odd = tuple(c[n - 1:n] for c in P) if last is None else last
        last = mul(tuple(c[m - 1:m] for c in pairs), odd)
    elif last is not None:  # the product's last pair has the replaced row in it
        last = mul(tuple(c[n - 2:n - 1] for c in P), last)
    scanned, product = _up_sweep(pairs, last)
    return _down_sweep(P, scanned), product


def _down_sweep(P: Quat, pairs: Quat) -> Quat:
    """Every prefix of ``P`` from the prefixes of its pairs (:func:`prefix_rows`' second
    half)."""
    n = P[0].shape[0]
    m = n // 2
    out = tuple(np.empty_like(c) for c in P)
    for o, c, s in zip(out, P, pairs):
        o[1:2 * m:2] = s  # row 2j + 1: the prefix of pairs 0..j
        o[0] = c[0]
    if n > 2:
        even = mul(tuple(s[0:(n - 1) // 2] for s in pairs), tuple(c[2:n:2] for c in P))
        for o, e in zip(out, even):
            o[2:n:2] = e  # row 2j: the prefix of pairs 0..j-1, times row 2j
    return out
