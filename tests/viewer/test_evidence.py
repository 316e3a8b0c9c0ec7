"""Issue 21, point 5: what the Overview, the L-curve and the Optimiser tabs say, read back from
the .rrd (headless, no viewer needed): the gyroscope's and the accelerometer's error before
and after as the core computed them, the L-curve of a well-posed fit called so, and the cost
axis holding at least a decade."""

from __future__ import annotations

import numpy as np
import pytest

import imucal
from imucal.synth import make_session
from viewer import paths as P
from viewer import readback as rb
from viewer.blueprint import blueprint
from viewer.evidence import evidence_titles
from viewer.optimiser import cost_falls
from viewer.plot2d import log_axis
from viewer.recording import save_recording


@pytest.fixture(scope="module")
def sample(tmp_path_factory, sample_session_path):
    result = imucal.calibrate(imucal.load_session(sample_session_path))
    path = tmp_path_factory.mktemp("evidence") / "sample.rrd"
    save_recording(result, path)
    return result, path


def _series(rrd, path: str) -> tuple[np.ndarray, np.ndarray, dict]:
    v = rb.values(rrd, path)
    xy = np.reshape(np.asarray(v["Points2D:positions"], float), (-1, 2))
    return xy[:, 0], xy[:, 1], v


def _view_names(bp) -> list[str]:
    """Every view's title in the layout, in order (tab by tab, left to right)."""
    import rerun.blueprint as rrb

    out = []

    def walk(c):
        if isinstance(c, rrb.Container):
            for x in c.contents:
                walk(x)
        elif isinstance(c, rrb.View):
            out.append(str(c.name))

    walk(bp.root_container)
    return out


def test_overview_rotation_error_per_turn_before_and_after(sample):
    result, rrd = sample
    g = result.segments[0].gyro
    starts = result.block_times[:, 0]
    for name, want in (("before", g.angle_before), ("after", g.angle_after)):
        x, y, v = _series(rrd, P.series(P.EVIDENCE_TURNS, name))
        np.testing.assert_array_equal(np.asarray(v["deg"], float), want)
        np.testing.assert_allclose(10.0 ** y, np.abs(want), rtol=1e-5)  # float32
        np.testing.assert_allclose(x, starts[1:len(want) + 1], rtol=1e-6)  # its end
    # The evidence itself: the calibrated gyroscope carries gravity ~75x closer on the sample.
    rms = result.quality.gravity_angle_rms_deg
    assert rms.before > 20 * rms.after
    turns, blocks = evidence_titles(result)
    assert f"RMS {rms.before:.3g} before → {rms.after:.3g} after" in turns
    q = result.quality.static_norm_rms_mg
    assert f"RMS {q.before:.3g} before → {q.after:.3g} after" in blocks


def test_overview_block_norm_error_before_and_after(sample):
    result, rrd = sample
    q = result.quality
    for name, want in (("before", q.block_norm_error_before_mg),
                       ("after", q.block_norm_error_mg)):
        x, y, v = _series(rrd, P.series(P.EVIDENCE_BLOCKS, name))
        np.testing.assert_array_equal(np.asarray(v["mg"], float), want)  # signed, as computed
        np.testing.assert_allclose(10.0 ** y, np.abs(want), rtol=1e-5)  # float32
        np.testing.assert_allclose(x, result.block_middles, rtol=1e-6)
    assert np.sqrt(np.mean(q.block_norm_error_mg ** 2)) == pytest.approx(
        q.static_norm_rms_mg.after, rel=1e-9)


def test_overview_layout_shows_the_evidence_not_the_overlapping_gyro_magnitudes(sample):
    result, _ = sample
    names = _view_names(blueprint(result))
    turns, blocks = evidence_titles(result)
    assert turns in names and blocks in names
    assert not any(n.startswith("Gyroscope magnitude") for n in names)


def test_raw_counts_have_after_only(tmp_path):
    session, _ = make_session(poses=30, seed=3, acc_unit="counts", gyro_unit="counts")
    result = imucal.calibrate(session)
    rrd = tmp_path / "counts.rrd"
    save_recording(result, rrd)
    found = rb.entities(rrd)
    assert P.series(P.EVIDENCE_BLOCKS, "after") in found
    assert P.series(P.EVIDENCE_BLOCKS, "before") not in found
    _, _, v = _series(rrd, P.series(P.EVIDENCE_BLOCKS, "after"))
    np.testing.assert_array_equal(np.asarray(v["mg"], float), result.quality.block_norm_error_mg)


def test_well_posed_lcurve_says_no_corner_and_the_lambda_below_which_fits_agree(sample):
    result, rrd = sample
    lc = result.whole.lcurve
    # The sample's curve is flat to 0.1 % up to lambda = 0.001, where the "corner" was taken.
    assert lc.well_posed and lc.same_fit_until == lc.corner
    assert lc.lambdas[lc.same_fit_until] == pytest.approx(1e-3)
    rho, eta = lc.residual_norm, lc.solution_norm
    assert abs(eta[lc.same_fit_until] / eta[0] - 1) <= 1e-3
    k = lc.same_fit_until
    assert abs(rho[k] / rho[0] - 1) <= 1e-3 and abs(rho[k + 1] / rho[0] - 1) > 1e-3
    names = _view_names(blueprint(result))
    assert any("no corner, the fit is well posed: every λ up to 0.001 gives the same fit" in n
               for n in names)
    # the error against lambda comes first in the tab
    lcurve_tab = [n for n in names if "vs λ" in n or "L-curve" in n]
    assert lcurve_tab[0].startswith("Static norm error") and "all λ below 0.001" in lcurve_tab[0]
    _, _, corner = _series(rrd, P.LCURVE_CORNER)
    labels = corner["Points2D:labels"]
    assert (labels if isinstance(labels, str) else labels[0]) == "chosen λ = 0.001 (no corner)"


def test_ill_posed_lcurve_keeps_its_corner():
    """An L whose eta falls steeply before rho rises is not called well posed."""
    from imucal.stages.accel import LCurve

    lam = np.logspace(-6, 2, 17)
    t = np.log10(lam)
    rho = 1e-3 * (1 + 10.0 ** (t + 1))  # rises past lambda = 0.1
    eta = 1e-1 * (1 + 10.0 ** (-(t + 3)))  # falls until lambda = 1e-3
    lc = LCurve(lambdas=lam, residual_norm=rho, solution_norm=eta, thetas=np.zeros((17, 9)),
                corner=8, curvature=np.zeros(17))
    assert lc.same_fit_until == 0 and not lc.well_posed


def test_optimiser_cost_axis_spans_a_decade_and_the_title_says_the_fall(sample):
    result, rrd = sample
    falls = cost_falls(result, "accelerometer")
    assert len(falls) == 1 and 0 < falls[0] < 0.1  # the sample: a fall of ~0.06 %
    cost = np.asarray(result.whole.report.trace_cost, float)
    axis = log_axis(np.log10(cost), min_span=1.0)
    assert axis.hi - axis.lo >= 1.0
    # the points' scene height: the whole fall is a sliver of the plot, not its full height
    _, y, _ = _series(rrd, P.iteration_series("segment_1", "accelerometer", "log10_cost",
                                              "cost"))
    assert (y.max() - y.min()) / (axis.hi - axis.lo) < 0.01
    gyro = cost_falls(result, "gyroscope")
    assert len(gyro) == 1 and gyro[0] > 99.0  # a fall by thousands: said as a factor
    c = np.asarray(result.segments[0].gyro.report.trace_cost, float)
    names = _view_names(blueprint(result))
    assert f"Gyroscope: cost (log scale, a decade at least) per accepted step, fell " \
           f"{float(f'{c[0] / c[-1]:.3g}'):,.0f}-fold" in names  # 3,780-fold
    assert f"Accelerometer: cost (log scale, a decade at least) per accepted step, fell " \
           f"{falls[0]:.3g} %" in names
