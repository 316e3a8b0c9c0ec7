"""The compiled M1 kernel (windows.variance_sumsq) against the numpy operations it replaces:
the same values to the bit, on signals with a still sensor's small variance on a large offset,
spikes, windows crossing chunk boundaries, and short signals of one chunk."""

import numpy as np
import pytest

from imucal.numerics.windows import chunked_window_sums, variance_sumsq


def numpy_reference(z: np.ndarray, w: int, m: int, b: int, root: bool) -> np.ndarray:
    """The numpy sequence statistic_spans ran before the kernel (a span's M1)."""
    k = z.shape[0]
    y = np.empty((2 * k, z.shape[1]))
    y[:k] = z
    np.multiply(y[:k], y[:k], out=y[k:])
    s = chunked_window_sums(y, w, m, b)
    s *= 1.0 / w
    m1, m2 = s[:k], s[k:]
    np.multiply(m1, m1, out=m1)
    v = np.subtract(m2, m1, out=m2)
    np.maximum(v, 0.0, out=v)
    v *= w / max(w - 1, 1)
    out = np.multiply(v[0], v[0])
    for j in range(1, k):
        out += v[j] * v[j]
    return np.sqrt(out) if root else out


@pytest.mark.parametrize("length,w,b", [(5000, 101, 256), (3000, 7, 16384), (40000, 1001, 2048),
                                        (600, 200, 400), (1500, 2, 64)])
@pytest.mark.parametrize("root", [False, True])
def test_kernel_matches_numpy_to_the_bit(length, w, b, root):
    rng = np.random.default_rng(length + w)
    z = 9.81 + 1e-3 * rng.standard_normal((3, length))
    z[:, length // 3: length // 2] += rng.standard_normal((3, length // 2 - length // 3))
    z[1, 17] += 50.0  # a spike
    z -= z.mean(axis=1, keepdims=True)
    m = length - w + 1
    bb = max(w, min(b, length + 1))
    got = variance_sumsq(z, w, m, b, root=root)
    want = numpy_reference(z, w, m, bb, root)
    assert got.shape == (m,)
    assert np.array_equal(got, want)
    assert np.all(got >= 0.0) and got.max() > 1e-3  # not a trivial zero


def test_kernel_is_exact_on_rows_with_a_stride():
    """A view of a larger buffer (rows with a stride), as statistic_spans passes."""
    rng = np.random.default_rng(3)
    buf = rng.standard_normal((3, 3000))
    z = buf[:, :2500]
    assert np.array_equal(variance_sumsq(z, 50, 2451, 512),
                          numpy_reference(np.ascontiguousarray(z), 50, 2451, 512, False))
