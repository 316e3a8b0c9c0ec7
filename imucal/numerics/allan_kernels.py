"""Compiled inner loops of the pooled Allan variance (``allan.py``), the same floating-point
operations in the same order as the numpy they replace, so the sums are the same to the bit:

- a slice's second differences ``(S_{i+2m} - 2 S_{i+m}) + S_i`` (numpy: ``multiply`` by 2,
  ``subtract``, ``+=``; no fused multiply-add: numba contracts nothing without ``fastmath``),
  squared and summed per column in order from +0, as ``einsum("ij,ij->j", d, d)`` sums them;
- a C-ordered run's mean, its rows summed in order from +0 (as ``einsum("ij->j")``) over its
  length, subtracted from each row.

Without a per-slice ``d`` array, ``einsum`` or per-run temporaries (tested bit for bit against
the numpy in tests/numerics/test_allan_kernels.py). Single-threaded, cached (``rk4.jit``).
"""

from __future__ import annotations

import numpy as np

from imucal.numerics.rk4.jit import jit


@jit()
def kept_sum(S: np.ndarray, o: int, m: int, ka: np.ndarray, kb: np.ndarray) -> np.ndarray:
    """Per column, the sum over the start points ``[ka[r], kb[r])`` (in order; ``o``: the
    position of ``S[0]``) of ``(S_{i+2m} - 2 S_{i+m} + S_i)^2``, from +0 in order."""
    k = S.shape[1]
    out = np.zeros(k)
    for r in range(ka.shape[0]):
        for i in range(ka[r] - o, kb[r] - o):
            for c in range(k):
                d = (S[i + 2 * m, c] - S[i + m, c] * 2.0) + S[i, c]
                out[c] += d * d
    return out


@jit()
def centred_runs(xs: np.ndarray, s: np.ndarray, e: np.ndarray, out: np.ndarray) -> None:
    """``out``: the rows ``[s[r], e[r])`` of a C-ordered ``xs``, each run less its mean (its
    rows summed in order from +0, divided by its length), end to end."""
    k = xs.shape[1]
    mean = np.empty(k)
    p = 0
    for r in range(s.shape[0]):
        a, b = s[r], e[r]
        mean[:] = 0.0
        for i in range(a, b):
            for c in range(k):
                mean[c] += xs[i, c]
        for c in range(k):
            mean[c] = mean[c] / (b - a)
        for i in range(a, b):
            for c in range(k):
                out[p, c] = xs[i, c] - mean[c]
            p += 1
