"""The gyroscope fit holds none of the turn samples laid out (issue 12: a 6-hour 1 kHz session's
fit once held +564 MB of them): :class:`Transitions` keeps where each turn starts and ends, the
integration and the Jacobian read the rows of an ndarray where they lie, and gather those of
any other array a chunk of turns at a time, with the same numbers to the bit.

Allocations are measured with tracemalloc (numpy reports its buffers to it), not timed."""

from __future__ import annotations

import tracemalloc

import numpy as np
from row_only import RowOnly

# numba's import and the kernels' cache load allocate some 35 MB of Python objects once per
# process: imported here, not inside the measurements
import imucal.numerics.rk4.kernels  # noqa: F401
from imucal.stages.gyro_transitions import Transitions, gyro_model_of

RATE = 1000.0
STILL, TURN, POSES = 1000, 50_000, 40  # 39 turns of 50 000 steps: 47 MB of (x, y, z) float64


def _session() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(5)
    n = POSES * (STILL + TURN)
    t = np.arange(n) / RATE + rng.uniform(0.0, 2e-5, n)  # jittered: every dt its own
    w = rng.normal(0.0, 0.5, (n, 3)) + [0.01, -0.02, 0.005]
    start = np.arange(POSES) * (STILL + TURN)
    blocks = np.column_stack([t[start], t[start + STILL - 1]])
    return w, t, blocks


def _model():
    theta = np.r_[np.full(6, 1e-3), 1.01, 0.99, 1.02, 1e-3, -2e-3, 5e-4]
    return theta, (lambda th: gyro_model_of(th, np.array([0.01, -0.02, 0.005]), 1.0))


def test_the_fit_allocates_a_fraction_of_the_turn_samples() -> None:
    w, t, blocks = _session()
    theta, model_of = _model()
    u_prev = np.tile([0.0, 0.0, 1.0], (POSES - 1, 1))
    tracemalloc.start()
    try:
        before, _ = tracemalloc.get_traced_memory()
        tr = Transitions(w, t, blocks)
        q = tr.rotations(model_of(theta))
        J = tr.jacobian(model_of, theta, u_prev)
        held, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    turn_bytes = 3 * 8 * int(np.sum(tr.n_steps + 1))
    assert turn_bytes > 40e6 and q.shape == (POSES - 1, 4) and J.shape == (3 * (POSES - 1), 12)
    # Laid out (before 2026-11), the samples alone were 1.0 of this (with dt and dt^2, 1.7)
    # and held throughout; read in place, only the outputs are allocated.
    assert peak - before < 0.25 * turn_bytes
    assert held - before < 0.05 * turn_bytes


def test_gathered_a_chunk_at_a_time_the_numbers_are_the_same_to_the_bit() -> None:
    w, t, blocks = _session()
    theta, model_of = _model()
    u_prev = np.tile([0.0, 0.0, 1.0], (POSES - 1, 1))
    in_place = Transitions(w, t, blocks)
    x, tt = RowOnly(w), RowOnly(t)
    tracemalloc.start()
    try:
        before, _ = tracemalloc.get_traced_memory()
        tr = Transitions(x, tt, blocks)
        q = tr.rotations(model_of(theta))
        J = tr.jacobian(model_of, theta, u_prev)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert not tr.turns.in_place and in_place.turns.in_place
    np.testing.assert_array_equal(q, in_place.rotations(model_of(theta)))
    np.testing.assert_array_equal(J, in_place.jacobian(model_of, theta, u_prev))
    # one turn (some 50 000 rows, under a chunk's) at a time: 1.6 MB of samples and times
    turn_bytes = 3 * 8 * int(np.sum(tr.n_steps + 1))
    assert x.largest == tr.n_steps.max() + 1 and peak - before < 0.1 * turn_bytes
