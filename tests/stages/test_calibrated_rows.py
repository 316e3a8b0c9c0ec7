"""The run reads the calibrated signals a block, a turn or a chunk at a time (issue 12: at 6 h
and 1 kHz they are 1 GB, and ``calibrate`` no longer makes them whole): every row it reads is
the same to the bit as the row of the whole ``Calibration.apply``, over several segments and
the gaps between them, and reading them allocates a chunk, not the signal.

Allocations are measured with tracemalloc (numpy reports its buffers to it), not timed."""

from __future__ import annotations

import tracemalloc

import numpy as np

from imucal.models import SensorModel
from imucal.numerics.windows import block_means, segment_sums
from imucal.session import Session
from imucal.stages.apply import CHUNK_ROWS, Calibration, SegmentModels
from imucal.stages.guide import _peak_rates
from imucal.stages.quality import _block_figures, _norm_error_mg

N = 1_000_000  # 24 MB of (N, 3) float64


def _model(rng: np.random.Generator) -> SensorModel:
    return SensorModel(T=np.eye(3) + rng.normal(0, 0.01, (3, 3)), K=1 + rng.normal(0, 0.02, 3),
                       b=rng.normal(0, 0.05, 3))


def _case() -> tuple[Calibration, Session]:
    rng = np.random.default_rng(7)
    t = np.arange(N) / 1000.0
    acc = rng.normal(0, 0.01, (N, 3)) + [0.1, -0.2, 0.98]
    gyro = rng.normal(0, 0.5, (N, 3))
    # Three segments with gaps between them (the neighbours' mean model), pieces not on the
    # 64k-row grid of the whole, one shorter than a chunk.
    spans = [(0.0, 310.123), (333.3, 333.35), (401.0, 900.5)]
    segs = tuple(SegmentModels(t_start=a, t_end=b, acc=_model(rng), gyro=_model(rng))
                 for a, b in spans)
    cal = Calibration(segments=segs, acc_unit_raw="g", acc_unit="g", g=1.0,
                      gyro_unit_raw="rad/s")
    session = Session(t_acc=t, acc=acc, t_gyro=t, gyro=gyro, acc_unit="g", gyro_unit="rad/s",
                      source="test")
    return cal, session


def test_rows_are_the_whole_calibration_to_the_bit() -> None:
    cal, s = _case()
    whole = cal.apply(s)
    rng = np.random.default_rng(1)
    cuts = [(0, N), (N - 5, N), (0, 1), (CHUNK_ROWS - 1, CHUNK_ROWS + 1)]
    cuts += [(int(a), int(min(N, a + n))) for a, n in
             zip(rng.integers(0, N, 60), rng.integers(1, 3 * CHUNK_ROWS, 60))]
    for lo, hi in cuts:
        assert np.array_equal(cal.rows(s, "acc", lo, hi), whole.acc[lo:hi])
        assert np.array_equal(cal.rows(s, "gyro", lo, hi), whole.gyro[lo:hi])


def _chunked_norm_rms(x: np.ndarray, g: float, blocks: np.ndarray, chunk: int = 1 << 16
                      ) -> float:
    """The samples' norm RMS as a pass over the whole signal a chunk at a time computes it
    (each block's part in each chunk summed, a chunk's parts together, the chunks in order)."""
    total, starts, ends = 0.0, blocks[:, 0], blocks[:, 1]
    for c0 in range(0, len(x), chunk):
        c1 = min(len(x), c0 + chunk)
        i0 = int(np.searchsorted(ends, c0, side="right"))
        i1 = int(np.searchsorted(starts, c1, side="left"))
        if i1 > i0:
            dev = _norm_error_mg(x[c0:c1], g) ** 2
            total += float(np.sum(segment_sums(dev, np.maximum(starts[i0:i1], c0) - c0,
                                               np.minimum(ends[i0:i1], c1) - c0)))
    return float(np.sqrt(total / np.sum(ends - starts)))


def test_figures_from_rows_equal_the_whole_signal_and_allocate_a_chunk() -> None:
    cal, s = _case()
    whole = cal.apply(s)
    edges = np.sort(np.random.default_rng(2).choice(np.arange(1, N), 300, replace=False))
    blocks = edges.reshape(-1, 2)

    def rows(a: int, b: int) -> np.ndarray:
        return cal.rows(s, "acc", a, b)

    def gyro_rows(a: int, b: int) -> np.ndarray:
        return cal.rows(s, "gyro", a, b)

    tracemalloc.start()
    try:
        before, _ = tracemalloc.get_traced_memory()
        tracemalloc.reset_peak()
        means, rms = _block_figures(rows, blocks, 1.0, means=True)
        starts, ends = blocks[:-1, 1] - 1, blocks[1:, 0] + 1
        peaks = _peak_rates(gyro_rows, starts, ends, N)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert np.array_equal(means, block_means(whole.acc, blocks))
    assert rms == _chunked_norm_rms(whole.acc, 1.0, blocks)
    assert _block_figures(lambda a, b: whole.acc[a:b], blocks, 1.0, means=False)[1] == rms
    norm = np.linalg.norm(whole.gyro, axis=1)
    assert np.array_equal(peaks, [norm[a:b].max() for a, b in zip(starts, ends)])
    # A run of blocks (2^18 rows) and its grid-aligned copy, not the 24 MB signal.
    assert peak - before < 0.8 * whole.acc.nbytes, peak - before


def test_row_norms_are_numpys_norms_to_the_bit() -> None:
    from imucal.stages.quality import row_norms

    rng = np.random.default_rng(4)
    for scale in (1e-12, 1.0, 1e150):
        x = rng.standard_t(2, (5000, 3)) * scale
        assert np.array_equal(row_norms(x), np.linalg.norm(x, axis=1))
