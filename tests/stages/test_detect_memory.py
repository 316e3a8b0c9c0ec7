"""The static detector in memory bounded by a span of the signal (issue 12: +360 MB above the
session at 6 hours of 1 kHz, and the statistic kept whole, 173 MB): no temporary the length of
the signal. Allocations are measured with tracemalloc (numpy reports its buffers to it), not
timed."""

from __future__ import annotations

import tracemalloc

import numpy as np

from imucal.settings import Settings
from imucal.stages.detect_tuning import tune_detector

N = 4_000_000  # 96 MB of (N, 3) float64 at 1 kHz: M1 alone would be 32 MB, a clean copy 96


def _holds(n: int, rate: float = 1000.0, hold: float = 3.0, turn: float = 2.0,
           seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Still poses held ``hold`` s with smooth turns between them, a 5 s rest first."""
    rng = np.random.default_rng(seed)
    per, h = int((hold + turn) * rate), int(hold * rate)
    d = rng.normal(size=(n // per + 2, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    i = np.arange(n)
    f = 0.5 - 0.5 * np.cos(np.pi * np.clip((i % per - h) / (per - h), 0.0, 1.0))[:, None]
    x = (1.0 - f) * d[i // per] + f * d[i // per + 1]
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    x[:int(5 * rate)] = d[0]
    x += rng.normal(0.0, 0.003, (n, 3))
    return x, i / rate


def test_tuned_detector_holds_a_span_not_the_signal() -> None:
    acc, t = _holds(N)
    acc[[1_234_567, 3_000_001], [0, 2]] += [1e6, -5.0]  # outliers: the statistic's input
    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        before, _ = tracemalloc.get_traced_memory()
        det = tune_detector(acc, t, Settings().detect)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert len(det.blocks) == N // 5000 and det.window == 1011
    assert det.outliers.tolist() == [1_234_567, 3_000_001]
    # A span of M1 (2^17 values) and its running sums, a read of rows, the scan's bins (a
    # window / 16 samples each) and a strided sample: ~35 MB at any length. The statistic
    # kept whole (and a cleaned copy of the signal) made it more than the signal itself.
    assert peak - before < 0.45 * acc.nbytes
