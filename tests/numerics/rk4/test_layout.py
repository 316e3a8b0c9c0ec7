"""imucal.numerics.rk4.layout: StepLayout gathers each interval's own samples and integrates
them; integrate_transitions on the edge cases."""

import numpy as np

from imucal.numerics.rk4.integrate import integrate_buckets
from imucal.numerics.rk4.layout import StepLayout, integrate_transitions
from imucal.numerics.rk4.variational import sensitivity


def _recording(n=600, seed=0):
    rng = np.random.default_rng(seed)
    return np.cumsum(rng.uniform(0.008, 0.012, n)), rng.normal(0, 1.0, (n, 3))


def test_gather_holds_each_intervals_samples_then_zeros():
    t, w = _recording()
    starts, ends = np.array([0, 100, 590, 300]), np.array([50, 103, 599, 300])
    layout = StepLayout(t, starts, ends)
    comps = [w[:, j].copy() for j in range(3)]
    seen = set()
    for bucket, g in zip(layout.buckets, layout.gather(comps)):
        for col, k in enumerate(bucket.idx):
            seen.add(int(k))
            n = ends[k] - starts[k]
            for j in range(3):
                np.testing.assert_array_equal(g[j][:n + 1, col], w[starts[k]:ends[k] + 1, j])
                np.testing.assert_array_equal(g[j][n + 1:, col], 0.0)
    assert seen == {0, 1, 2, 3}


def test_methods_are_the_integration_and_the_sensitivity_of_its_buckets():
    t, w = _recording(seed=1)
    layout = StepLayout(t, np.array([0, 200]), np.array([150, 500]))
    samples = layout.gather([w[:, j].copy() for j in range(3)])
    M, b = np.eye(3) * 1.01, np.array([0.01, -0.02, 0.0])
    np.testing.assert_array_equal(layout.integrate(samples, [(M, b)]),
                                  integrate_buckets(layout.buckets, 2, samples, [(M, b)]))
    for a, r in zip(layout.sensitivity(samples, M, b),
                    sensitivity(layout.buckets, 2, samples, M, b)):
        np.testing.assert_array_equal(a, r)


def test_integrate_transitions_of_nothing_and_of_no_steps():
    t, w = _recording(seed=2)
    assert integrate_transitions(w, t, np.zeros(0, int), np.zeros(0, int)).shape == (0, 4)
    q = integrate_transitions(w, t, np.array([10, 20]), np.array([10, 25]))
    np.testing.assert_array_equal(q[0], [1.0, 0.0, 0.0, 0.0])  # no step: no rotation
    assert abs(q[1, 0]) < 1.0  # five steps of about 1 rad/s: a rotation


def test_integrate_transitions_composes_over_consecutive_intervals():
    # The rotation over [a, c] is the rotation over [a, b] followed by that over [b, c].
    t, w = _recording(seed=3)
    q = integrate_transitions(w, t, np.array([50, 50, 250]), np.array([400, 250, 400]))
    pw, px, py, pz = q[1]
    qw, qx, qy, qz = q[2]
    composed = np.array([pw * qw - px * qx - py * qy - pz * qz,
                         pw * qx + px * qw + py * qz - pz * qy,
                         pw * qy - px * qz + py * qw + pz * qx,
                         pw * qz + px * qy - py * qx + pz * qw])
    np.testing.assert_allclose(q[0] * np.sign(q[0, 0]), composed * np.sign(composed[0]),
                               atol=1e-13)
