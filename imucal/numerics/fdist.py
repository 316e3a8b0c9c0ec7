"""The F distribution's tail and its inverse, without scipy.

``scipy.stats`` takes a large part of a second to import; the grouping needs one tail
probability per tested split. The tail is the regularised incomplete beta function,
``P(F > f) = I_x(d2/2, d1/2)`` with ``x = d2 / (d2 + d1 f)``, evaluated by its continued
fraction (modified Lentz), as in Numerical Recipes §6.4.
"""

from __future__ import annotations

import math

_EPS = 1e-15
_TINY = 1e-300
_MAX_TERMS = 500


def _beta_cf(a: float, b: float, x: float) -> float:
    """Continued fraction of the incomplete beta function (converges for x < (a+1)/(a+b+2))."""
    qab, qap, qam = a + b, a + 1.0, a - 1.0
    c, d = 1.0, 1.0 - qab * x / qap
    d = 1.0 / (d if abs(d) > _TINY else _TINY)
    h = d
    for m in range(1, _MAX_TERMS + 1):
        m2 = 2 * m
        for num in (m * (b - m) * x / ((qam + m2) * (a + m2)),
                    -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))):
            d = 1.0 + num * d
            d = 1.0 / (d if abs(d) > _TINY else _TINY)
            c = 1.0 + num / c
            c = c if abs(c) > _TINY else _TINY
            h *= d * c
        if abs(d * c - 1.0) < _EPS:
            break
    return h


def betainc(a: float, b: float, x: float) -> float:
    """The regularised incomplete beta function ``I_x(a, b)`` for ``a, b > 0``."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    log_front = (math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x)
                 + b * math.log1p(-x))
    if x < (a + 1.0) / (a + b + 2.0):
        return math.exp(log_front) * _beta_cf(a, b, x) / a
    return 1.0 - math.exp(log_front) * _beta_cf(b, a, 1.0 - x) / b


def f_sf(f: float, d1: float, d2: float) -> float:
    """``P(F > f)`` for F with ``d1`` and ``d2`` degrees of freedom."""
    if not f > 0.0:
        return 1.0
    if math.isinf(f):
        return 0.0
    return betainc(d2 / 2.0, d1 / 2.0, d2 / (d2 + d1 * f))


def f_isf(q: float, d1: float, d2: float) -> float:
    """The ``f`` with ``P(F > f) = q`` (``0 < q < 1``), by bisection on the beta argument."""
    lo, hi = 0.0, 1.0  # I_x(d2/2, d1/2) rises from 0 to 1 with x; f falls as x rises
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if betainc(d2 / 2.0, d1 / 2.0, mid) < q:
            lo = mid
        else:
            hi = mid
        if hi - lo < 1e-16 * hi:
            break
    x = 0.5 * (lo + hi)
    return d2 * (1.0 - x) / (d1 * x)
