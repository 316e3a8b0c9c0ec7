"""The stages' sums over still blocks and detector bins take the signal a run at a time (issue 12:
a worker's memory is bounded by the session): no temporary the size of the signal, and the same
numbers to the bit as the whole-array formula they replace.

Allocations are measured with tracemalloc (numpy reports its buffers to it), not timed."""

from __future__ import annotations

import tracemalloc

import numpy as np

from imucal.numerics.windows import centred_segment_sums, segment_sums
from imucal.stages.detect_score import Prefix
from imucal.stages.group import block_mean_variance

N = 2_000_000  # 48 MB of (N, 3) float64: a copy would dwarf the 6 MB a run's buffer takes


def _signal() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(3)
    x = rng.normal(0.0, 0.01, (N, 3)) + [0.1, -0.2, 0.98]
    # Sorted blocks with gaps, one longer than a run (CHUNK_ROWS) and one reaching the end.
    edges = np.sort(rng.choice(np.arange(1, N - 400_000), 400, replace=False))
    blocks = edges.reshape(-1, 2)
    blocks = np.vstack([blocks, [[N - 350_000, N]]])
    return x, blocks


def _peak(f, *args):
    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        before, _ = tracemalloc.get_traced_memory()
        out = f(*args)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return out, peak - before


def test_centred_segment_sums_are_the_whole_array_sums_without_a_copy() -> None:
    x, blocks = _signal()
    c = x[0].copy()
    (s1, s2), peak = _peak(centred_segment_sums, x, blocks[:, 0], blocks[:, 1], c)
    xc = x - c
    assert np.array_equal(s1, segment_sums(xc, blocks[:, 0], blocks[:, 1]))
    assert np.array_equal(s2, segment_sums(xc * xc, blocks[:, 0], blocks[:, 1]))
    assert peak < 0.4 * x.nbytes  # the longest block (350 000 rows) and a run; a copy: 1.0


def test_block_mean_variance_allocates_a_run_not_the_signal() -> None:
    x, blocks = _signal()
    _, peak = _peak(block_mean_variance, x, blocks)
    assert peak < 0.4 * x.nbytes  # the longest block (350 000 rows) and a run; a copy: 1.0


def test_detector_bin_sums_are_the_whole_array_sums_without_a_copy() -> None:
    x, _ = _signal()
    d = 7  # N is not a multiple: the last bin is partial
    pre, peak = _peak(Prefix, x, d)
    sums = np.add.reduceat(x - x[0], np.arange(0, N, d), axis=0)
    assert np.array_equal(pre.s1, np.concatenate([np.zeros((1, 3)), np.cumsum(sums, axis=0)]))
    # The running sums themselves are N / d rows; the centred copy was N.
    assert peak < 0.2 * x.nbytes + 2 * pre.s1.nbytes


def test_saturated_runs_are_the_mask_a_chunk_at_a_time() -> None:
    from imucal.numerics.windows import mask_of_runs, runs_of_true
    from imucal.stages.saturation import blocks_meeting, blocks_with, saturated_runs

    x, blocks = _signal()
    # Flat runs at an axis's extreme: across chunk edges (4096), one too short, one at the end.
    x[4090:4200, 0] = 0.5
    x[8190:8195, 2] = 0.5
    x[20_000:20_004, 1] = -0.5  # 4 samples: not saturated
    x[N - 7:, 1] = 0.5
    x[500_000:500_050, 1] = 0.5
    whole = np.zeros(N, dtype=bool)  # the whole-signal rule: runs of 5+ at an axis's extreme
    for axis in range(3):
        for extreme in (x[:, axis].max(), x[:, axis].min()):
            r = runs_of_true(x[:, axis] == extreme)
            whole |= mask_of_runs(r[(r[:, 1] - r[:, 0]) >= 5], N)
    assert whole.any()
    runs, peak = _peak(saturated_runs, x, 5, 4096)  # small chunks: many runs cross an edge
    np.testing.assert_array_equal(mask_of_runs(runs, N), whole)
    assert np.all(runs[1:, 0] > runs[:-1, 1])  # sorted and disjoint
    assert peak < N  # less than a boolean mask of the signal
    np.testing.assert_array_equal(blocks_meeting(runs, blocks), blocks_with(whole, blocks))
