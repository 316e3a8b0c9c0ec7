"""The compiled kernel of the windowed variances of method.md §1 (M1), imported on first use
(numba costs ~0.7 s to import: not paid by a run that never computes M1 over long spans)."""

from __future__ import annotations

import numpy as np

from imucal.numerics.rk4.jit import jit


@jit()
def variance_sumsq_kernel(zc, w, m, b, inv, scale, root):  # pragma: no cover - compiled
    """The kernel of ``windows.variance_sumsq``: per row, the chunked running sums of
    ``windows.chunked_window_sums`` (each ``np.cumsum`` a sequential sum: the same additions in the
    same order), then the variance and the sum over rows in the order of numpy's elementwise
    operations there, so every value is the same to the bit."""
    k, length = zc.shape
    nch = -(-(length + 1) // b)
    need = min(m + w - (nch - 1) * b, b)
    out = np.zeros(m)
    e1 = np.empty(nch * b)
    e2 = np.empty(nch * b)
    t1 = np.empty(nch)
    t2 = np.empty(nch)
    for r in range(k):
        for c in range(nch):
            top = b if c < nch - 1 else need
            a1 = 0.0
            a2 = 0.0
            for j in range(top):
                i = c * b + j
                y1 = zc[r, i] if i < length else 0.0
                y2 = y1 * y1
                if j == 0:
                    a1 = y1
                    a2 = y2
                else:
                    a1 = a1 + y1
                    a2 = a2 + y2
                e1[i] = a1 - y1  # the inclusive running sum less the sample (E -= Y)
                e2[i] = a2 - y2
            t1[c] = a1  # the chunk's totals
            t2[c] = a2
        for i in range(m):
            c = i // b
            s1 = e1[i + w] - e1[i]
            s2 = e2[i + w] - e2[i]
            if i - c * b >= b - w:  # the window runs into the next chunk: add this one's total
                s1 = s1 + t1[c]
                s2 = s2 + t2[c]
            s1 = s1 * inv
            s2 = s2 * inv
            v = s2 - s1 * s1
            if v < 0.0:  # np.maximum(v, 0): a NaN stays NaN
                v = 0.0
            v = v * scale
            out[i] = v * v if r == 0 else out[i] + v * v
    if root:
        for i in range(m):
            out[i] = np.sqrt(out[i])
    return out
