"""The gyroscope fit holds a slab of the turn samples at a time, not all of them laid out (issue 12:
a 6-hour 1 kHz session's fit held +564 MB of them): :class:`Transitions` keeps where each turn
starts and how many steps it takes, and the integration and the Jacobian gather their rows from
the session's array when they read them, with the same numbers to the bit as the samples
gathered once.

Allocations are measured with tracemalloc (numpy reports its buffers to it), not timed."""

from __future__ import annotations

import tracemalloc

import numpy as np

from imucal.numerics.rk4 import StepLayout
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
    # Laid out, the samples alone were 1.0 of this (with dt and dt^2, 1.7) and held throughout.
    assert peak - before < 0.25 * turn_bytes
    assert held - before < 0.05 * turn_bytes


def test_gathered_a_slab_at_a_time_the_numbers_are_the_same_to_the_bit() -> None:
    w, t, blocks = _session()
    theta, model_of = _model()
    model = model_of(theta)
    tr = Transitions(w, t, blocks)
    eager = StepLayout(t, tr.starts, tr.ends)
    samples = eager.gather([np.ascontiguousarray(w[:, i]) for i in range(3)])
    assert np.array_equal(tr.rotations(model),
                          eager.integrate(samples, [(model.matrix, model.b)])[0])
    for got, want in zip(tr.layout.sensitivity(tr.rates, model.matrix, model.b),
                         eager.sensitivity(samples, model.matrix, model.b)):
        assert np.array_equal(got, want)
    for lazy, whole in zip(tr.layout.buckets, eager.buckets):
        assert np.array_equal(lazy.dt[:], whole.dt) and np.array_equal(lazy.dt2[:], whole.dt2)
