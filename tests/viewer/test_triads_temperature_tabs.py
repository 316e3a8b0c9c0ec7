"""Issue 24, item 4: the Triads and Temperature tabs, read back from the .rrd (headless): each
other triad's still-block gravity against the reference's in mg (a synthetic triad turned by a
known rotation), its rotation with the standard error, the figures side by side; the bias
against temperature with the data points per still block on their heating or cooling leg, the
fitted polynomial, the span seen. A session of one triad and no temperature model records
exactly what it did before, and has neither tab."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest
from rerun.chunk import RrdReader
from scipy.spatial.transform import Rotation

import imucal
from imucal.pipeline import calibrate_temperature, calibrate_triads
from imucal.synth import SecondTriad, TemperatureProfile, make_session
from viewer import paths as P
from viewer import readback as rb
from viewer.blueprint import blueprint
from viewer.recording import save_recording
from viewer.temperature import temperature_note
from viewer.triads import triads_note

ROTATION_DEG = 3.0


@pytest.fixture(scope="module")
def tt(tmp_path_factory):
    """A second triad (with its gyroscope) turned 3 deg from the first, and the temperature
    going 15 -> 45 -> 15 deg C over the session (heating, then cooling)."""
    session, truth = make_session(
        poses=24, seed=1, second_acc=(SecondTriad(rotation_deg=ROTATION_DEG, gyro=True),),
        temperature=TemperatureProfile(back=True))
    result = calibrate_triads(calibrate_temperature(imucal.calibrate(session)),
                              temperature=True)
    path = tmp_path_factory.mktemp("tt") / "tt.rrd"
    save_recording(result, path)
    return result, truth, path


def test_each_blocks_gravity_difference_in_mg(tt):
    result, truth, rrd = tt
    a = result.triads[0].agreement
    mid = result.block_middles[a.used]
    series = {w: rb.scalars(rrd, P.triad(2, w)) for w in ("before_mg", "unrotated_mg",
                                                            "after_mg", "held_out_mg")}
    for t, _ in series.values():
        np.testing.assert_allclose(t, mid, atol=1e-9)
    # Calibrated but each triad in its own frame, the difference is the known rotation's:
    # |u - R' u| for each block's gravity direction u (the triad's frame is R' of the
    # reference's), 0 to 52 mg for 3 deg; the calibrations' own errors add about a mg.
    u = a.u / np.linalg.norm(a.u, axis=1)[:, None]
    expected = np.linalg.norm(u - u @ truth.triads[0].R, axis=1) * 1e3
    _, unrotated = series["unrotated_mg"]
    np.testing.assert_allclose(unrotated, expected, atol=2.0)
    assert unrotated.max() > 40 and np.median(unrotated) > 25
    _, after = series["after_mg"]
    _, held = series["held_out_mg"]
    np.testing.assert_allclose(held, a.held_out_mg, rtol=1e-12)
    assert np.sqrt(np.mean(held**2)) == pytest.approx(a.held_out_rms_mg, rel=1e-12)
    assert np.sqrt(np.mean(after**2)) < 1.5 and np.all(held >= after * 0.9)
    _, before = series["before_mg"]
    np.testing.assert_allclose(before, a.before_mg, rtol=1e-12)
    assert np.median(before) > 30  # raw triads: a 3 % scale error and 50 mg bias per axis


def test_rotation_with_its_standard_error_and_the_figures_side_by_side(tt):
    result, truth, rrd = tt
    tri = result.triads[0]
    info = rb.values(rrd, P.triad(2, "info"))
    true_rv = np.degrees(Rotation.from_matrix(truth.triads[0].R).as_rotvec())
    rv, std = np.asarray(info["rotvec_deg"]), np.asarray(info["std_deg"])
    np.testing.assert_allclose(std, tri.agreement.rotation.std_deg, rtol=1e-12)
    assert np.all(np.abs(rv - true_rv) < 4 * std + 0.005), (rv, true_rv, std)
    assert info["angle_deg"] == pytest.approx(ROTATION_DEG, abs=0.05)
    assert info["angle_deg"] == pytest.approx(tri.agreement.angle_deg, abs=1e-9)
    np.testing.assert_allclose(np.reshape(info["R"], (3, 3)), tri.agreement.rotation.R)
    g_rv = np.asarray(info["gyro_rotvec_deg"])  # the gyroscope's, from the turns (M14)
    assert np.all(np.abs(g_rv - true_rv) < 4 * np.asarray(info["gyro_std_deg"]) + 0.05)
    assert info["name"] == tri.name == "acc a2" and info["gyro"] == tri.gyro
    assert info["turns"] == tri.gyro_agreement.turns > 10
    note = rb.values(rrd, P.TRIADS_NOTE)["TextDocument:text"]
    assert note == triads_note(result)
    header = note.splitlines()[2]
    assert "reference" in header and "2: acc a2" in header  # a column per triad
    assert f"{tri.agreement.angle_deg:.3f} ± {tri.agreement.rotation.std_total_deg:.3f} deg" \
        in note
    assert f"{result.quality.static_norm_rms_mg.after:.3g} mg" in note  # the reference's own
    own = tri.result.quality.static_norm_rms_mg.after
    assert f"{own:.3g} mg" in note  # ... beside the other triad's


def _plot_series(rrd, path: str) -> tuple[np.ndarray, dict]:
    v = rb.values(rrd, path)
    return np.reshape(np.asarray(v["Points2D:positions"], float), (-1, 2)), v


def test_accelerometer_bias_against_temperature_and_the_span(tt):
    result, truth, rrd = tt
    fit = next(f for f in result.temperature if f.sensor == "accelerometer")
    lo, hi = fit.span
    curves = []
    for i, a in enumerate("xyz"):
        xy, v = _plot_series(rrd, P.series(P.temp_plot("accelerometer", "bias"), f"bias_{a}"))
        np.testing.assert_allclose(xy[:, 0], v["degC"], rtol=1e-6)
        np.testing.assert_allclose(xy[:, 1], v["mg"], rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(v["mg"], (fit.bias_at(v["degC"]) - fit.b0)[:, i] * 1e3,
                                   rtol=1e-12)
        curves.append(np.asarray(v["mg"]))
    temps = np.asarray(v["degC"])
    assert temps[0] < lo and temps[-1] > hi  # drawn beyond the span seen ...
    mg = np.column_stack(curves)
    outside = (temps < lo) | (temps > hi)
    ends = (fit.bias_at(np.array([lo, hi])) - fit.b0) * 1e3  # the model at the span's ends
    edge = np.where(temps[outside, None] < lo, ends[0], ends[1])
    np.testing.assert_allclose(mg[outside], edge, atol=1e-9)  # ... and held flat there
    # the change over the ramp is the synthetic truth's (8, -6, 4 mg from 20 to 40 deg C)
    at = np.interp([20.0, 40.0], temps, mg[:, 0]), np.interp([20.0, 40.0], temps, mg[:, 1])
    true = np.diff(truth.temperature.acc_drift(np.array([20.0, 40.0])), axis=0)[0] * 1e3
    np.testing.assert_allclose([np.diff(at[0])[0], np.diff(at[1])[0]], true[:2], atol=1.0)
    marks = [rb.values(rrd, f"{P.temp_plot('accelerometer', 'bias')}/frame/mark_{k}/label")
             for k in (0, 1)]
    assert [m["Points2D:labels"] for m in marks] == [f"{lo:.1f} °C",
                                                    f"{hi:.1f} °C (span seen)"]


def test_block_points_on_their_heating_and_cooling_legs(tt):
    result, _, rrd = tt
    duration = result.session.duration
    gyro = next(f for f in result.temperature if f.sensor == "gyroscope")
    points = (gyro.points() - gyro.b0) * np.degrees(1.0)
    seen = 0
    for i, a in enumerate("xyz"):
        base = P.temp_plot("gyroscope", f"bias_{a}")
        for leg, first_half in (("heating", True), ("cooling", False)):
            xy, v = _plot_series(rrd, P.series(base, leg))
            block = np.asarray(v["block"], int)
            k = np.searchsorted(gyro.used, block)
            np.testing.assert_allclose(v["deg/s"], points[k, i], rtol=1e-12)
            np.testing.assert_allclose(xy[:, 0], gyro.temps[k], rtol=1e-6)
            # heating blocks lie in the ramp's first half, cooling ones in its second
            assert np.all((result.block_middles[block] < duration / 2) == first_half)
            seen += len(block)
        _, fitted = _plot_series(rrd, P.series(base, "fit"))
        np.testing.assert_allclose(fitted["deg/s"], (gyro.bias_at(fitted["degC"])
                                                     - gyro.b0)[:, i] * np.degrees(1.0))
    assert seen == 3 * len(gyro.used) == 3 * 24
    acc = next(f for f in result.temperature if f.sensor == "accelerometer")
    norm = P.temp_plot("accelerometer", "norm")
    heat = rb.values(rrd, P.series(norm, "constant_heating"))
    cool = rb.values(rrd, P.series(norm, "constant_cooling"))
    np.testing.assert_allclose(np.r_[heat["mg"], cool["mg"]], acc.before_mg, rtol=1e-12)
    after = rb.values(rrd, P.series(norm, "with_polynomial"))
    np.testing.assert_allclose(after["mg"], acc.residuals, rtol=1e-12)
    # the polynomial explains the drift: the blocks' norm error drops
    assert np.sqrt(np.mean(acc.before_mg**2)) > 3 * np.sqrt(np.mean(acc.residuals**2))
    t_heat, v_heat = rb.scalars(rrd, P.temp_blocks("heating"))
    t_cool, _ = rb.scalars(rrd, P.temp_blocks("cooling"))
    assert len(t_heat) == len(t_cool) == 12 and t_heat.max() < t_cool.min()
    assert np.all(np.diff(v_heat) > 0)  # the temperature rises along the heating leg
    note = rb.values(rrd, P.TEMP_NOTE)["TextDocument:text"]
    assert note == temperature_note(result) and "hysteresis" in note


def test_tabs_only_when_their_data_exist(tt):
    result, _, _ = tt
    names = [t.name for t in blueprint(result).root_container.contents]
    assert names[-3:] == ["Triads", "Temperature", "Summary"]
    session, _ = make_session(poses=24, seed=1, second_acc=(SecondTriad(rotation_deg=2.0),))
    triads_only = calibrate_triads(imucal.calibrate(session))
    names = [t.name for t in blueprint(triads_only).root_container.contents]
    assert "Triads" in names and "Temperature" not in names


IDS = ("rerun.controls.RowId", "RecordingInfo:start_time")


def _bytes(column: pa.Array) -> bytes:
    """A column's Arrow data as bytes (NaN equal to NaN, unlike ``Array.equals``)."""
    sink = pa.BufferOutputStream()
    batch = pa.record_batch([column], names=["c"])
    with pa.ipc.new_stream(sink, batch.schema) as w:
        w.write_batch(batch)
    return sink.getvalue().to_pybytes()


def _content(rrd) -> list[tuple[str, tuple, list[tuple[str, tuple]], list[bytes]]]:
    """Every chunk of the recording, its ids (chunk and rows) and the recording's start time
    left out (they differ between any two runs): entity path, the schema's and the fields'
    metadata (sorted) and the Arrow columns' bytes, sorted (the batcher may send an entity's
    chunks in another order)."""
    out = []
    for chunk in RrdReader(rrd).stream().to_chunks():
        b = chunk.to_record_batch()
        meta = tuple(sorted((k, v) for k, v in (b.schema.metadata or {}).items()
                            if k != b"rerun:id"))
        fields = [(f.name, tuple(sorted((f.metadata or {}).items()))) for f in b.schema
                  if f.name not in IDS]
        out.append((chunk.entity_path, meta, fields,
                    [_bytes(b.column(n)) for n, _ in fields]))
    return sorted(out)


def test_one_triad_records_what_it_did_before(tmp_path, monkeypatch):
    """A session of one triad without a temperature model: the same recording, chunk for
    chunk, as without the two tabs' code (what every recording was before them), and the
    same layout."""
    import viewer.blueprint as bp
    import viewer.recording as rec

    session, _ = make_session(poses=12, seed=5)
    result = imucal.calibrate(session)
    assert not result.triads and not result.temperature
    now = tmp_path / "now.rrd"
    save_recording(result, now)
    with monkeypatch.context() as m:
        m.setattr(rec, "log_triads", lambda *a: None)
        m.setattr(rec, "log_temperature", lambda *a: None)
        m.setattr(bp, "triads_tab", lambda *a: pytest.fail("no Triads tab"))
        m.setattr(bp, "temperature_tab", lambda *a: pytest.fail("no Temperature tab"))
        before = tmp_path / "before.rrd"
        save_recording(result, before)
    assert _content(now) == _content(before)
    assert rb.blueprint_containers(now) == rb.blueprint_containers(before)
    assert rb.blueprint_views(now) == rb.blueprint_views(before)
    assert not [e for e in rb.entities(now) if e.startswith(("triads", "temperature"))]


def test_scale_against_temperature_where_the_data_determine_it(tmp_path):
    """Scales that change by 300, -200, 100 ppm per deg C: the tab's third accelerometer plot
    draws K(T)/K - 1 as the fit has it, about the truth's slope."""
    profile = TemperatureProfile(acc_scale=(3e-4, -2e-4, 1e-4))
    session, _ = make_session(poses=30, seed=1, temperature=profile)
    result = calibrate_temperature(imucal.calibrate(session))
    fit = next(f for f in result.temperature if f.sensor == "accelerometer")
    assert fit.scale_slope is not None
    rrd = tmp_path / "scale.rrd"
    save_recording(result, rrd)
    base = P.temp_plot("accelerometer", "scale")
    for i, a in enumerate("xyz"):
        v = rb.values(rrd, P.series(base, f"scale_{a}"))
        temps, ppm = np.asarray(v["degC"]), np.asarray(v["ppm"])
        np.testing.assert_allclose(ppm, (fit.scale_at(temps)[:, i] / fit.model.K[i] - 1) * 1e6,
                                   rtol=1e-12)
        inside = (temps > fit.span[0]) & (temps < fit.span[1])
        slope = np.polyfit(temps[inside], ppm[inside], 1)[0]
        assert slope == pytest.approx(profile.acc_scale[i] * 1e6, abs=40)  # ppm per deg C
    views = [v.name for v in blueprint(result).root_container.contents[-2].contents[0].contents]
    assert views[-1] == "Accelerometer scale K(T)/K − 1 (ppm)"


def test_every_triads_temperature_fit_is_drawn(tmp_path):
    """Both IMUs drift, each by its own coefficients (synth's --acc2 --gyro2 --temperature):
    the Temperature tab draws the second triad's bias curves beside the reference's, its
    gyroscope's still blocks and fit on each axis's plot, and its orders in the note; each
    follows its own truth, not the other's."""
    from imucal.cli.synth_triads import ACC2_TEMP, GYRO2_TEMP

    profile = TemperatureProfile(acc2=ACC2_TEMP, gyro2=GYRO2_TEMP)
    session, truth = make_session(poses=30, seed=2, acc_rate=200.0, temperature=profile,
                                  second_acc=SecondTriad(gyro=True, same_clock=True))
    result = calibrate_triads(calibrate_temperature(imucal.calibrate(session)),
                              temperature=True)
    rrd = tmp_path / "both.rrd"
    save_recording(result, rrd)
    (tri,) = result.triads
    acc2, gyro2 = tri.result.temperature
    base = P.temp_plot("accelerometer", "bias")
    drawn = []
    for i, a in enumerate("xyz"):
        v = rb.values(rrd, P.series(base, f"t2_bias_{a}"))
        temps, mg = np.asarray(v["degC"]), np.asarray(v["mg"])
        np.testing.assert_allclose(mg, (acc2.bias_at(temps) - acc2.b0)[:, i] * 1e3, rtol=1e-12)
        drawn.append(np.diff(np.interp([20.0, 40.0], temps, mg))[0])
    # its change from 20 to 40 deg C is its own truth's, 17 mg from the first's
    own, first = (np.diff(f(np.array([20.0, 40.0])), axis=0)[0] * 1e3
                  for f in (profile.acc2_drift, profile.acc_drift))
    np.testing.assert_allclose(drawn, own, atol=1.0)
    assert np.linalg.norm(own - first) > 10.0
    pts = (gyro2.points() - gyro2.b0) * np.degrees(1.0)
    for i, a in enumerate("xyz"):
        plot = P.temp_plot("gyroscope", f"bias_{a}")
        v = rb.values(rrd, P.series(plot, "t2_points"))
        np.testing.assert_allclose(v["deg/s"], pts[:, i], rtol=1e-12)
        np.testing.assert_allclose(v["degC"], gyro2.temps, rtol=1e-12)
        fitted = rb.values(rrd, P.series(plot, "t2_fit"))
        np.testing.assert_allclose(fitted["deg/s"], (gyro2.bias_at(fitted["degC"])
                                                     - gyro2.b0)[:, i] * np.degrees(1.0))
        want = np.degrees(profile.gyro2_drift(np.asarray(fitted["degC"]))[:, i]
                          - profile.gyro2_drift(np.array([fitted["degC"][0]]))[0, i])
        inside = (np.asarray(fitted["degC"]) > gyro2.span[0]) & (
            np.asarray(fitted["degC"]) < gyro2.span[1])
        got = np.asarray(fitted["deg/s"]) - fitted["deg/s"][0]
        err = (got - want)[inside] - np.mean((got - want)[inside])
        assert np.sqrt(np.mean(err**2)) < 0.02  # deg/s: the shape of its own truth
    note = rb.values(rrd, P.TEMP_NOTE)["TextDocument:text"]
    assert note == temperature_note(result)
    assert f"- **acc a2, accelerometer**: order {acc2.order} over" in note
    assert f"- **acc a2, gyroscope**: order {gyro2.order} over" in note
