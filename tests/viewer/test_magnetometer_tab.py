"""Issue 23, item 5: the Magnetometer tab, read back from the .rrd (headless): the raw and the
calibrated samples, the fitted ellipsoid, the norm and the dip over time with the disturbed
part marked, and the coverage, each against the core's MagFit; a session without a
magnetometer has none of it."""

from __future__ import annotations

import numpy as np
import pytest

import imucal
from imucal.synth import make_session
from viewer import paths as P
from viewer import readback as rb
from viewer.blueprint import blueprint
from viewer.magnetometer import MAG_POINTS, mag_note, mag_stream, mag_titles
from viewer.recording import save_recording

DISTURBED = (20.0, 30.0)  # s: a magnet near the sensor (synth's disturbance interval)


@pytest.fixture(scope="module")
def mag(tmp_path_factory):
    session, truth = make_session(poses=30, seed=3, mag_rate=50, mag_disturbance=DISTURBED)
    result = imucal.calibrate(session)
    path = tmp_path_factory.mktemp("mag") / "mag.rrd"
    save_recording(result, path)
    return result, truth, path


def _points(rrd, path: str) -> tuple[np.ndarray, dict]:
    v = rb.values(rrd, path)
    return np.reshape(np.asarray(v["Points3D:positions"], float), (-1, 3)), v


def _strips(rrd, path: str) -> np.ndarray:
    strips = rb.values(rrd, path)["LineStrips3D:strips"]
    return np.concatenate([np.reshape(np.asarray(s, float), (-1, 3)) for s in strips])


def test_raw_and_calibrated_samples_are_the_fits(mag):
    result, _, rrd = mag
    fit, stream = mag_stream(result)
    raw, v = _points(rrd, P.MAG_RAW_SAMPLES)
    idx = np.asarray(v["sample_index"], int)
    assert 1000 < len(idx) <= MAG_POINTS and len(idx) == len(raw)
    np.testing.assert_allclose(raw, stream.values[idx], rtol=1e-6)  # float32
    used = np.asarray(v["used"], bool)
    np.testing.assert_array_equal(used, fit.used[idx])
    assert 0 < (~used).sum() < used.sum()  # the disturbed part is drawn, apart
    cal, cv = _points(rrd, P.MAG_CAL_SAMPLES)
    np.testing.assert_array_equal(np.asarray(cv["sample_index"], int), idx)
    np.testing.assert_allclose(cal, fit.apply(stream.values[idx]), rtol=1e-5,
                               atol=1e-6 * fit.field)
    # on the sphere where the field was undisturbed (noise 0.4 % of it), off it where not
    r = np.linalg.norm(cal, axis=1) / fit.field - 1
    assert np.abs(r[used]).max() < 0.02 and np.median(np.abs(r[~used])) > 0.1


def test_ellipsoid_is_the_fitted_one_in_the_raw_frame(mag):
    result, truth, rrd = mag
    fit = result.magnetometer
    pts = _strips(rrd, P.MAG_RAW_ELLIPSOID)
    assert np.abs(fit.norm_error(pts)).max() < 1e-5  # on |M (m - b)| = F, float32
    # its centre is the hard iron, and it is the raw samples' shape: not a sphere
    np.testing.assert_allclose(0.5 * (pts.max(axis=0) + pts.min(axis=0)), fit.b,
                               atol=0.02 * fit.field)
    np.testing.assert_allclose(fit.b, truth.mag.b, atol=0.01 * fit.field)
    assert np.ptp(np.linalg.norm(pts - fit.b, axis=1)) > 0.05 * fit.field  # soft iron
    u = np.array([[1.0, 0, 0], [0, 0.6, 0.8]])
    np.testing.assert_allclose((fit.ellipsoid(u) - fit.b) @ fit.M.T / fit.field, u,
                               atol=1e-12)
    sphere = _strips(rrd, P.MAG_CAL_SPHERE)
    np.testing.assert_allclose(np.linalg.norm(sphere, axis=1), fit.field, rtol=1e-6)


def test_norm_over_time_and_the_disturbed_part(mag):
    result, _, rrd = mag
    fit, stream = mag_stream(result)
    t = stream.t
    err = 100 * fit.norm_error(stream.values)
    tu, eu = rb.scalars(rrd, P.MAG_NORM_USED)
    np.testing.assert_allclose(tu, t[fit.used], atol=1e-6)
    np.testing.assert_allclose(eu, err[fit.used], rtol=1e-9)
    tl, el = rb.scalars(rrd, P.MAG_NORM_LEFT_OUT)
    np.testing.assert_allclose(el, err[~fit.used], rtol=1e-9)
    assert tl.min() >= DISTURBED[0] - 2 and tl.max() <= DISTURBED[1] + 2
    assert np.sqrt(np.mean(eu ** 2)) == pytest.approx(fit.quality.norm_rms_pct, rel=1e-6)
    assert np.median(np.abs(el)) > 10  # the magnet: tens of % of the field
    ts, states = rb.column(rrd, P.MAG_DISTURBED, "StateChange:state")
    d = fit.disturbances
    assert len(d) == 1 and d[0].kind == "norm"
    np.testing.assert_allclose(ts, [d[0].t_start, d[0].t_end], atol=1e-6)
    assert [s if isinstance(s, str) else s[0] for s in states] == ["norm", ""]


def test_dip_per_still_block(mag):
    result, _, rrd = mag
    fit = result.magnetometer
    mid = result.block_times.mean(axis=1)
    np.testing.assert_array_equal(fit.block_times, result.block_times)
    tu, du = rb.scalars(rrd, P.MAG_DIP_USED)
    np.testing.assert_allclose(tu, mid[fit.block_used], atol=1e-6)
    np.testing.assert_allclose(du, fit.block_dip_deg[fit.block_used], rtol=1e-12)
    tl, dl = rb.scalars(rrd, P.MAG_DIP_LEFT_OUT)
    left = ~fit.block_used & np.isfinite(fit.block_dip_deg)
    assert left.sum() == 3  # the blocks inside the disturbed part
    np.testing.assert_allclose(tl, mid[left], atol=1e-6)
    assert np.all((tl > DISTURBED[0] - 5) & (tl < DISTURBED[1] + 5))
    _, fitted = rb.scalars(rrd, P.MAG_DIP_FIT)
    np.testing.assert_array_equal(fitted, [fit.dip_deg] * 2)
    assert fit.dip_deg == pytest.approx(mag[1].mag.dip_deg, abs=0.1)
    assert np.std(du, ddof=1) == pytest.approx(fit.quality.dip_spread_deg, rel=1e-9)


def test_coverage_in_the_info_note_and_titles(mag):
    result, _, rrd = mag
    fit = result.magnetometer
    q = fit.quality
    info = rb.values(rrd, P.MAG_INFO)
    assert info["coverage"] == q.coverage and info["field"] == fit.field
    assert info["norm_rms_pct"] == q.norm_rms_pct
    assert info["samples_used"] == int(fit.used.sum())
    assert q.missing is not None and info["missing"] == q.missing  # 87 %: +z never reached
    note = rb.values(rrd, P.MAG_NOTE)["TextDocument:text"]
    assert note == mag_note(fit)
    assert f"reached {q.coverage:.0%} of directions; {q.missing}" in note
    assert "19.0-31.0 s" in note  # the disturbed part, as the core says it
    raw_title, _ = mag_titles(result)
    assert f"coverage {q.coverage:.0%}" in raw_title


def test_the_soft_irons_lcurve_is_drawn_with_its_corner(mag):
    """M8r's L-curve on the tab, read back: every lambda's (log10 rho, log10 eta) and the
    corner, the core's LCurve's; 30 poses reach the directions: no corner, the plain fit."""
    result, _, rrd = mag
    lc = result.magnetometer.lcurve
    pts = rb.values(rrd, P.MAG_LCURVE_POINTS)
    np.testing.assert_array_equal(pts["lambda"], lc.lambdas)
    xy = np.reshape(np.asarray(pts["Points2D:positions"], float), (-1, 2))
    np.testing.assert_allclose(xy, np.column_stack([np.log10(lc.residual_norm),
                                                    np.log10(lc.solution_norm)]), rtol=1e-5)
    corner = rb.values(rrd, P.MAG_LCURVE_CORNER)
    assert corner["lambda"] == result.magnetometer.lam == lc.lambdas[lc.corner]
    np.testing.assert_allclose(np.ravel(corner["Points2D:positions"]), xy[lc.corner], rtol=1e-6)
    label = corner["Points2D:labels"]
    label = label if isinstance(label, str) else label[0]
    assert lc.well_posed and label == f"chosen λ = {lc.lambdas[lc.corner]:.3g} (no corner)"
    assert "λ = " in mag_note(result.magnetometer)


def test_tab_only_with_a_magnetometer(mag, tmp_path):
    result, _, _ = mag
    tabs = [t.name for t in blueprint(result).root_container.contents]
    assert tabs[-2:] == ["Magnetometer", "Summary"]
    session, _ = make_session(poses=12, seed=5)
    plain = imucal.calibrate(session)
    assert plain.magnetometer is None
    rrd = tmp_path / "plain.rrd"
    save_recording(plain, rrd)
    assert not [e for e in rb.entities(rrd) if e.startswith("magnetometer")]
    assert "Magnetometer" not in [t.name for t in blueprint(plain).root_container.contents]


@pytest.mark.viewer
def test_native_viewer_draws_the_magnetometer_tab(native_viewer, mag, tmp_path):
    """The tab as a person sees it (headless native viewer): every view has drawn data, the
    3D scenes the samples' colours (orange raw, blue calibrated). ``IMUCAL_SCREENSHOT_DIR``
    keeps the tab's screenshot (docs/tab-magnetometer.png, in README)."""
    import time

    from test_viewer_screens import (
        _colourful,
        _image,
        _keep,
        _shot,
        _show_tab,
        _tabs,
        _wait,
        headless_viewer,
    )

    from viewer.columns import CALIBRATED, RAW

    _, _, rrd = mag
    with headless_viewer(tmp_path) as client:
        client.open([str(rrd)])
        _wait(lambda: not client.get_state().loading, 30, "the recording to load")
        bp = client.get_blueprint()
        tabs = _tabs(bp.blueprint)
        assert [name for _, name, _ in tabs][-2:] == ["Magnetometer", "Summary"]
        ref, _, views = next(t for t in tabs if t[1] == "Magnetometer")
        _show_tab(client, bp, ref)

        def share(view) -> float:
            img = _image(_shot(client, view[0]))
            if view[1] == "TextDocument":
                return float((img.max(axis=-1) > 150).mean())
            if view[1] == "3D":  # the samples' own colour, the one the title names
                colour = RAW if view[2].startswith("Raw") else CALIBRATED
                c = np.array([(colour >> s) & 255 for s in (24, 16, 8)])
                return float((np.abs(img - c).max(axis=-1) < 40).mean())
            return float(_colourful(img).mean())

        time.sleep(1.0)
        deadline = time.monotonic() + 30
        while True:
            shares = {v[2]: share(v) for v in views}
            if all(s > 0.002 for s in shares.values()) or time.monotonic() > deadline:
                break
            time.sleep(0.5)
        _keep("tab-magnetometer.png", _shot(client))
        assert all(s > 0.002 for s in shares.values()), shares
        assert len(views) == 7  # with the soft iron's L-curve (M8r)
        errors = [(v.name, r.summary) for v in client.get_state().views
                  if v.visible for r in v.reports if r.severity.lower() == "error"]
        assert not errors, errors
