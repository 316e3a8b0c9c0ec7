"""imucal.numerics.rk4.prefix_scan: every prefix against the products written out, and the
shared up-sweep against the scan and the ordered product each alone, to the bit."""

import numpy as np
import pytest

from imucal.numerics.rk4.hamilton import mul
from imucal.numerics.rk4.prefix_scan import prefix_and_product, prefix_rows
from imucal.numerics.rk4.product import SMALL, product_rows


def _rows(L, K, seed):
    rng = np.random.default_rng(seed)
    return tuple(rng.normal(size=(L, K)) for _ in range(4))


@pytest.mark.parametrize("L", [1, 2, 3, 7, 16, 33])
def test_every_prefix_is_the_product_of_the_rows_before(L):
    P = _rows(L, 3, L)
    Q = prefix_rows(P)
    acc = tuple(c[0] for c in P)
    for n in range(L):
        if n:
            acc = mul(acc, tuple(c[n] for c in P))
        for a, b in zip(acc, Q):
            np.testing.assert_allclose(b[n], a, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("L, K", [(1, 5), (2, 5), (3, 4000), (9, 3300), (10, 300), (59, 552),
                                  (60, 41), (197, 166), (255, 9), (1000, 1)])
def test_the_shared_up_sweep_gives_each_to_the_bit(L, K):
    # odd and even lengths at every level (the product folds an odd last row in, the scan
    # does not), above and below SMALL (where the product turns to stacked matrix products)
    P = _rows(L, K, L * K)
    Q, q = prefix_and_product(P)
    for got, want in zip(Q, prefix_rows(P)):
        np.testing.assert_array_equal(got, want)
    for got, want in zip(q, product_rows(P)):
        np.testing.assert_array_equal(got, want)


def test_both_of_the_products_paths_are_met():
    # (59, 552): elementwise at 59, 29, 14 and 7 rows, stacked from 3; (1000, 1): stacked only
    assert 7 * 552 > SMALL >= 3 * 552 and 1000 * 1 <= SMALL
