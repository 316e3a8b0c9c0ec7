"""The 2D plots' drawing (viewer/plot2d.py, viewer/lcurve.py): ticks, legend places, labels
that never overprint each other. Headless, no viewer needed."""

from __future__ import annotations

import numpy as np
import pytest

from viewer.lcurve import _label_box, _overlaps, _thin
from viewer.plot2d import LABEL_PX, _legend_places, linear_axis, log_axis, nice_ticks, tick_labels


def test_nice_ticks_are_round_and_few():
    np.testing.assert_allclose(nice_ticks(0.0, 1.0), [0.0, 0.25, 0.5, 0.75, 1.0])
    t = nice_ticks(0.9712, 1.0043)
    assert 2 <= len(t) <= 5 and np.all((t >= 0.9712) & (t <= 1.0043))
    assert tick_labels(t) == [f"{v:.2f}" for v in t]  # 0.98, 0.99, 1.00: two decimals
    assert tick_labels(np.array([5.7702e-4, 5.7704e-4])) == ["5.7702e-4", "5.7704e-4"]


def test_axes_hold_their_data():
    v = np.array([-0.0757, -0.0083, -0.0485, np.nan])
    a = linear_axis(v)
    assert a.lo < -0.0757 and a.hi > -0.0083 and len(a.ticks) == len(a.labels) >= 2
    flat = linear_axis(np.full(5, 0.99))  # a flat series still gets a range around it
    assert flat.lo < 0.99 < flat.hi
    lg = log_axis(np.log10([1e-8, 1e-3, 1e3]))
    assert lg.log and lg.lo < -8 and lg.hi > 3 and 3 <= len(lg.ticks) <= 6
    np.testing.assert_allclose([float(lab) for lab in lg.labels], 10.0**lg.ticks, rtol=1e-9)


def test_legend_names_are_a_label_apart_and_inside():
    ends = np.array([50.0, 52.0, 51.0, 300.0, 299.0])
    y = _legend_places(ends, 0.0, 200.0)
    s = np.sort(y)
    assert np.all(np.diff(s) >= LABEL_PX - 1e-9)
    assert s[0] >= 0.0 and s[-1] <= 200.0
    assert abs(y[0] - 50.0) < 2 * LABEL_PX  # near its curve's end


def test_point_labels_never_overlap_and_leave_the_corner_its_own():
    x = np.linspace(0, 300, 31)  # points 10 units apart: far closer than a label is wide
    scene = np.column_stack([x, np.full_like(x, 100.0)])
    labels = [f"λ={i}" for i in range(31)]
    corner = _label_box(scene[5], "corner λ = 5", 7.0)
    taken = [corner]
    kept = _thin(scene, labels, 5, taken)
    assert kept[5] == ""  # the corner's label is its own, placed first
    boxes = [corner] + [_label_box(scene[i], lab, 3.0) for i, lab in enumerate(kept) if lab]
    assert 1 < len(boxes) < 31
    for i, a in enumerate(boxes):
        for b in boxes[i + 1:]:
            assert not _overlaps(a, b, gap=0.0), (a, b)


@pytest.mark.parametrize("n", [1, 2])
def test_legend_places_for_few_names(n):
    y = _legend_places(np.arange(n, dtype=float), 0.0, 100.0)
    assert len(y) == n and np.all((y >= 0) & (y <= 100))


def test_one_spike_does_not_set_the_magnitude_plots_range():
    from viewer.blueprint import robust_range

    rng = np.random.default_rng(0)
    v = np.concatenate([1.0 + 0.03 * rng.standard_normal(20_000), [9.0], [np.nan]])
    lo, hi = robust_range(v)
    assert 0.85 < lo < 0.95 and 1.05 < hi < 1.15  # the raw and calibrated lines stay apart
    assert robust_range(np.full(10, 1.0)) is None  # flat: the viewer's own range
