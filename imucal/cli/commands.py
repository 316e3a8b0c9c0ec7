"""The commands: calibrate, apply, synth, view. Each parses its options and calls the core
(and, for --rrd and view, the viewer)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from imucal.cli.app import app
from imucal.cli.options import (
    ACC_UNITS,
    APPLY_INPUT_OPTIONS,
    DEFAULTS,
    GYRO_UNITS,
    INPUT_OPTIONS,
    SETTING_OPTIONS,
    SessionArg,
    VerboseOpt,
    _one_of,
    at_least,
    build_settings,
    choice,
    fraction,
    ip_address,
    load_kwargs,
    non_negative,
    pick,
    positive,
    shared_options,
    usage_error,
)
from imucal.cli.outputs import (
    Progress,
    check_inputs,
    check_magnitudes,
    check_outputs,
    fmt_rate,
    gyro_sidecar,
    removed_lines,
    viewer_available,
    write_signals,
    written_tables,
)
from imucal.cli.summary import print_summary
from imucal.errors import ImucalError

# --- commands ----------------------------------------------------------------------------------


# Output paths are taken as typed (str): a Path would drop the "/" of "--out newname/".


@app.command()
@shared_options(INPUT_OPTIONS, SETTING_OPTIONS)
def calibrate(
    session: SessionArg,
    out: Annotated[str, typer.Option("--out", "-o", metavar="CALIB.json", show_default=False,
                                     help="Calibration file to write (JSON).")],
    rrd: Annotated[str | None, typer.Option(
        "--rrd", metavar="RUN.rrd", help="Also save a Rerun recording of every step.")] = None,
    calibrated: Annotated[str | None, typer.Option(
        "--calibrated", metavar="OUT.parquet|.csv|.mat",
        help="Also write the calibrated signals.")] = None,
    allow_poor: Annotated[bool, typer.Option(
        "--allow-poor", help="Write the outputs even when the verdict is 'not usable' (and "
                             "exit 0).")] = False,
    spec: Annotated[Path | None, typer.Option(
        "--spec", metavar="LIMITS.toml", show_default=False,
        help="Limits the unit must be within (as for 'imucal batch'): out of them, the "
             "verdict is 'not usable'.")] = None,
    all_imus: Annotated[bool, typer.Option(
        "--all-imus", help="Also calibrate every other accelerometer triad of the file (other "
                           "IMUs of a log, a2x… columns), each with its own gyroscope, and put "
                           "each in the reference's frame: the calibrated one, which "
                           "--acc/--gyro choose (method.md §11).")] = False,
    triad: Annotated[list[str] | None, typer.Option(
        "--triad", metavar="NAME", help="Also calibrate this other accelerometer triad (a "
                                        "stream or IMU name; repeat for several), as "
                                        "--all-imus does for all.")] = None,
    temperature: Annotated[bool, typer.Option(
        "--temperature", help="Fit each sensor's bias as a polynomial in the file's temperature "
                              "stream (order 0-3 by cross-validation; never extrapolated "
                              "beyond the temperatures seen; method.md §12).")] = False,
    same_device: Annotated[list[Path] | None, typer.Option(
        "--same-device", metavar="SESSION", show_default=False,
        help="Another recording of the same device at another temperature (repeat for "
             "several): the bias in temperature is fitted to all their still poses "
             "(method.md §12); implies --temperature.")] = None,
    reference: Annotated[str | None, typer.Option(
        "--reference", metavar="NAME", show_default=False,
        help="The reference triad, every other one put in its frame: a table's a, a2, a3, a "
             "log's stream or IMU name [default: the first].")] = None,
    ranges: Annotated[list[str] | None, typer.Option(
        "--range", metavar="NAME=G", show_default=False,
        help="A triad's full-scale range in g (repeat for each): a low-range and a high-range "
             "accelerometer are combined (acx… in imucal apply; method.md M18) [default: which "
             "clips, from the data].")] = None,
    options: dict[str, Any] = None,  # INPUT_OPTIONS and SETTING_OPTIONS
    verbose: VerboseOpt = False,
) -> None:
    """Calibrate a recording and write the calibration file (and optionally more).

    The summary opens with the verdict: good, usable with caveats, or not usable, with the
    reason and the next step. A run that is not usable writes nothing and exits 1 unless
    --allow-poor. Every output is written to a temporary file and renamed into place only when
    all are complete: a failed or interrupted run changes no file.
    """
    settings = build_settings(**pick(options, SETTING_OPTIONS))
    check_magnitudes(settings)
    from imucal.cli.apply_triads import stated_ranges

    stated = stated_ranges(ranges, bool(all_imus or triad))
    load_kw = load_kwargs(**pick(options, INPUT_OPTIONS))
    inputs = [session, load_kw["gyro_path"], spec, *(same_device or [])]
    check_inputs(inputs)
    limits = None
    if spec is not None:
        from imucal.fleet.spec import load_spec

        limits = load_spec(spec)  # before any work: a bad spec is one line, nothing run
    if calibrated is not None:
        from imucal.io.export import output_format

        output_format(calibrated)
    from imucal.io.atomic import Transaction

    side = _sidecar(calibrated)
    tx = Transaction([out, calibrated, side, rrd], inputs=inputs, owned=_owned(side, calibrated))
    save_recording = None
    if rrd is not None:
        with viewer_available():
            from viewer.recording import save_recording

    progress = Progress(verbose)
    import imucal

    with tx:
        with progress.stage(f"loading {session.name}"):
            sess = imucal.load_session(session, **load_kw)
            if reference is not None:
                from imucal.stages.apply_triads import reference_session

                sess = reference_session(sess, reference)
        with progress.stage(f"calibrating {len(sess.acc)} samples (detect, group, fit)"):
            try:
                result = imucal.calibrate(sess, **settings)
            except ImucalError as e:
                if not (all_imus or triad):
                    raise
                # A file no triad calibrates from (a flight): where to see its IMUs anyway.
                raise ImucalError(f"{e.problem}; imucal inspect shows how the file's IMUs "
                                  "disagree as logged", source=e.source, field=e.field) from None
        if same_device:
            from imucal.pipeline import calibrate_same_device

            runs = [result]
            for other in same_device:
                with progress.stage(f"calibrating {other.name} (the same device)"):
                    runs.append(imucal.calibrate(imucal.load_session(other, **load_kw),
                                                 **settings))
            result = calibrate_same_device(runs)
        elif temperature:
            from imucal.pipeline import calibrate_temperature

            result = calibrate_temperature(result)
            if not result.temperature:
                raise ImucalError("--temperature: the file holds no temperature stream (a "
                                  "temp column, or a log's) covering the still poses",
                                  source=str(session))
        if all_imus or triad:
            from imucal.pipeline import calibrate_triads

            with progress.stage("calibrating the other triads"):
                result = calibrate_triads(result, "all" if all_imus else triad,
                                          temperature or bool(same_device))
                from imucal.pipeline import combine_triads

                result = combine_triads(result, stated)
        if limits is not None:
            result = _judged_by_spec(result, limits)
        if result.verdict is not None and not result.verdict.usable and not allow_poor:
            # Nothing is written (the transaction is left without a commit): a script's
            # `imucal calibrate ... && flash` stops here. The summary says why in full.
            print_summary(result, [], verbose=verbose)
            raise ImucalError(f"not usable: {result.verdict.reason}; nothing written "
                              "(--allow-poor writes it anyway)", source=str(session))
        with progress.stage(f"writing {out}"), tx.writing(out) as tmp:
            imucal.save_calibration(result, tmp)
        if calibrated is not None:
            with progress.stage(f"writing {calibrated}"):
                write_signals(tx, calibrated, result.calibrated)
        if rrd is not None and save_recording is not None:
            with progress.stage(f"writing {rrd}"), tx.writing(rrd) as tmp, open(tmp, "wb") as f:
                save_recording(result, f)
        tx.commit()
    written = [out]
    if calibrated is not None:
        written += written_tables(Path(calibrated), result.calibrated)
    written += [rrd] if rrd is not None else []
    print_summary(result, written, verbose=verbose)
    if tx.removed:
        print("\n".join(removed_lines(tx.removed, result.calibrated)))


def _judged_by_spec(result, limits):
    """The run with a maker's limits folded into its verdict (the same check as a batch's)."""
    import dataclasses

    from imucal.fleet.spec import check
    from imucal.fleet.summary import result_columns
    from imucal.stages.verdict import with_spec

    found = check(limits, result_columns(result))
    return dataclasses.replace(result, verdict=with_spec(
        result.verdict, found.to_dict() | {"limits": limits.limits}, limits.source))


def _sidecar(table: str | None) -> Path | None:
    if table is None or Path(table).suffix.lower() == ".mat":
        return None
    return gyro_sidecar(Path(table))


def _owned(side: Path | None, table: str | None) -> dict[Path, str]:
    """The sidecar is a name the user did not give: imucal replaces or removes only a sidecar
    it wrote itself (imucal.io.atomic, owned)."""
    return {} if side is None else {side: f"the gyroscope table of {table}"}


@app.command()
@shared_options(APPLY_INPUT_OPTIONS)
def apply(
    calibration: Annotated[Path, typer.Argument(metavar="CALIB.json", show_default=False,
                                                help="Calibration file from 'imucal calibrate'.")],
    session: SessionArg,
    out: Annotated[str, typer.Option(
        "--out", "-o", metavar="OUT.parquet|.csv|.mat", show_default=False,
        help="Calibrated signals to write; the format follows the name.")],
    reference: Annotated[str | None, typer.Option(
        "--reference", metavar="NAME", show_default=False,
        help="Write every triad in this triad's frame (a2, a stream or IMU name) [default: "
             "the calibration's reference].")] = None,
    mag_unit: Annotated[str, typer.Option(
        "--mag-unit", metavar="field|norm", callback=_one_of("field", "norm"),
        help="The magnetometer's mx, my, mz in the field's own unit, or divided by the "
             "calibrated field's norm (|m| = 1).")] = "field",
    options: dict[str, Any] = None,  # INPUT_OPTIONS
    verbose: VerboseOpt = False,
) -> None:
    """Apply a calibration file to a recording and write the calibrated signals.

    The recording's units must be those the calibration was fitted on (a mismatch is refused).
    """
    from imucal.io.export import output_format

    output_format(out)
    load_kw = load_kwargs(**pick(options, INPUT_OPTIONS))
    inputs = [calibration, session, load_kw["gyro_path"]]
    check_inputs(inputs)
    from imucal.io.atomic import Transaction

    side = _sidecar(out)
    tx = Transaction([out, side], inputs=inputs, owned=_owned(side, out))
    progress = Progress(verbose)
    import imucal

    with tx:
        with progress.stage(f"reading {calibration.name}"):
            cal = imucal.load_calibration(calibration)
        with progress.stage(f"loading {session.name}"):
            # One segment applies to every sample alike: time, and so --rate, cannot matter.
            sess = imucal.load_session(session, number_samples=len(cal.segments) == 1,
                                       **load_kw)
        with progress.stage("applying"):
            from imucal.cli.apply_triads import applied

            signals, triad_lines = applied(cal, calibration, sess, reference)
            if mag_unit == "norm":
                signals = signals.mag_normalised(cal, str(calibration))
        with progress.stage(f"writing {out}"):
            write_signals(tx, out, signals)
        tx.commit()
    import numpy as np

    from imucal.io.time_base import NUMBERED_NOTE

    norm = signals.acc_norm
    span = "no time" if NUMBERED_NOTE in sess.notes else f"{sess.duration:.1f} s"
    lines = [f"session         {sess.source}: {span}, accelerometer "
             f"{len(sess.acc)} samples ({sess.acc_unit}), "
             + (f"gyroscope {len(sess.gyro)} samples ({sess.gyro_unit})" if sess.has_gyro
                else "no gyroscope"),
             f"calibration     {calibration}: {len(cal.segments)} segment(s)",
             f"output          accelerometer in {signals.acc_unit} (median |a| "
             f"{float(np.median(norm)):.5g}, |g| = {cal.g:g})"
             + (", gyroscope in rad/s" if signals.gyro is not None else "")
             + _mag_output(out, signals, mag_unit)]
    lines += triad_lines
    if sess.has_gyro and signals.gyro is None:
        lines.append("warnings:\n  - the calibration has no gyroscope model: gyroscope not "
                     "written")
    if sess.notes:
        from imucal.cli.apply_triads import notes_applied

        lines.append("notes:")
        lines += [f"  - {n}" for n in notes_applied(sess.notes, signals.columns)]
    lines += [f"wrote {w}" for w in written_tables(Path(out), signals)]
    lines += removed_lines(tx.removed, signals)
    print("\n".join(lines))


def _mag_output(out: str | Path, signals, mag_unit: str = "field") -> str:
    """What became of the magnetometer: calibrated (M8) beside the others, or kept out of a
    table because its clock is its own."""
    from imucal.io.export import mag_rows

    if signals.mag is None:
        return ""
    if Path(out).suffix.lower() == ".mat" or mag_rows(signals) is not None:
        return (", magnetometer (mx, my, mz) " + ("in its raw unit" if mag_unit == "field"
                                                  else "in units of the calibrated field"))
    return (", magnetometer not written: its clock is its own (write OUT.mat for its "
            "mag and t_mag)")


def _activity(value: str | None) -> str | None:
    if value is not None and value not in ("walk", "jumps", "desk", "flight"):
        raise typer.BadParameter(f"expected walk, jumps, desk or flight, got {value!r}")
    return value


@app.command()
def synth(
    out: Annotated[Path, typer.Argument(metavar="OUT.mat|OUT.csv", show_default=False,
                                        help="Session file to write (MATLAB v5, or CSV).")],
    truth: Annotated[Path | None, typer.Option(
        "--truth", metavar="PATH", show_default=False,
        help="Where to write the true parameters [default: OUT's full name and .truth.json, "
             "e.g. my.csv.truth.json: never the truth of another OUT].")] = None,
    poses: Annotated[int | None, typer.Option(
        "--poses", metavar="N", callback=at_least(2), show_default=False,
        help="Number of still poses [default: 30].")] = None,
    minutes: Annotated[float | None, typer.Option(
        "--minutes", metavar="M", callback=positive, show_default=False,
        help="Session length; sets the number of poses from the durations.")] = None,
    seed: Annotated[int, typer.Option("--seed", help="Random seed.")] = 0,
    still: Annotated[float, typer.Option(
        "--still", metavar="S", callback=positive, help="Seconds still in each pose.")] = 3.0,
    move: Annotated[float, typer.Option(
        "--move", metavar="S", callback=positive, help="Seconds of each turn.")] = 2.0,
    init_still: Annotated[float, typer.Option(
        "--init-still", metavar="S", callback=positive,
        help="Seconds still at the start.")] = 5.0,
    acc_rate: Annotated[float, typer.Option(
        "--acc-rate", metavar="HZ", callback=positive, help="Accelerometer rate.")] = 100.0,
    gyro_rate: Annotated[float | None, typer.Option(
        "--gyro-rate", metavar="HZ", callback=positive, show_default=False,
        help="Gyroscope rate [default: the accelerometer's].")] = None,
    acc_noise: Annotated[float, typer.Option(
        "--acc-noise", metavar="G", callback=non_negative,
        help="Accelerometer white noise per axis, g.")] = 0.003,
    gyro_noise: Annotated[float, typer.Option(
        "--gyro-noise", metavar="RAD/S", callback=non_negative,
        help="Gyroscope white noise per axis, rad/s.")] = 0.003,
    drift: Annotated[float, typer.Option(
        "--drift", metavar="RAD/S", callback=non_negative,
        help="Total change of the gyroscope bias over the session.")] = 0.0,
    change_at: Annotated[float | None, typer.Option(
        "--change-at", metavar="FRACTION", callback=fraction, show_default=False,
        help="Switch to new sensor parameters after this fraction of the poses.")] = None,
    acc_unit: Annotated[str, typer.Option(
        "--acc-unit", metavar="g|m/s^2|counts",
        callback=choice(ACC_UNITS, "g, m/s^2 or counts", allow_auto=False),
        help="Unit of the written accelerometer.")] = "g",
    gyro_unit: Annotated[str, typer.Option(
        "--gyro-unit", metavar="rad/s|deg/s|counts",
        callback=choice(GYRO_UNITS, "rad/s, deg/s or counts", allow_auto=False),
        help="Unit of the written gyroscope.")] = "rad/s",
    preamble: Annotated[bool, typer.Option(
        "--preamble", help="CSV: key,value lines above the header stating the rate and the "
                           "initial still period, and no time column.")] = False,
    cut_last_line: Annotated[bool, typer.Option(
        "--cut-last-line", help="CSV: end in the middle of the last row, as a logger killed "
                                "mid-write does.")] = False,
    mag_rate: Annotated[float | None, typer.Option(
        "--mag-rate", metavar="HZ", callback=positive, show_default=False,
        help="Add a magnetometer (gauss, columns mx, my, mz of a CSV) at this rate, which "
             "must divide the accelerometer's; hard and soft iron and its rotation to the "
             "accelerometer drawn, the truth in the truth file.")] = None,
    mag_field: Annotated[float, typer.Option(
        "--mag-field", metavar="GAUSS", callback=positive,
        help="The local field's norm.")] = 0.5,
    mag_dip: Annotated[float, typer.Option(
        "--mag-dip", metavar="DEG", help="The field's dip below the horizon.")] = 65.0,
    mag_noise: Annotated[float, typer.Option(
        "--mag-noise", metavar="GAUSS", callback=non_negative,
        help="Magnetometer white noise per axis.")] = 0.002,
    mag_disturbance: Annotated[tuple[float, float] | None, typer.Option(
        "--mag-disturbance", metavar="T0 T1", show_default=False,
        help="A magnet carried with the sensor from T0 to T1 s (0.3 of the field).")] = None,
    activity: Annotated[str | None, typer.Option(
        "--activity", metavar="walk|jumps|desk|flight", callback=_activity, show_default=False,
        help="Everyday use instead of a calibration session (rare still moments, sway, taps; "
             "a flight: rests before take-off, motors' vibration; method.md §10), with the "
             "calibration before the drift written beside it.")] = None,
    drift_gyro_bias: Annotated[str | None, typer.Option(
        "--drift-gyro-bias", metavar="X,Y,Z", show_default=False,
        help="--activity: the gyroscope bias's change since calibration, deg/s.")] = None,
    drift_acc_bias: Annotated[str | None, typer.Option(
        "--drift-acc-bias", metavar="X,Y,Z", show_default=False,
        help="--activity: the accelerometer bias's change, mg.")] = None,
    drift_acc_scale: Annotated[str | None, typer.Option(
        "--drift-acc-scale", metavar="X,Y,Z", show_default=False,
        help="--activity: the accelerometer scales' change, %.")] = None,
    stream: Annotated[str | None, typer.Option(
        "--stream", metavar="-|tcp://HOST:PORT|udp://HOST:PORT", show_default=False,
        help="Also send the session as a device would, a line per sample (t,ax,ay,az,gx,gy,gz): "
             "to standard output, to one TCP client (listening on HOST:PORT) or as UDP "
             "datagrams, for 'imucal capture'.")] = None,
    speed: Annotated[float | None, typer.Option(
        "--speed", metavar="X", callback=positive, show_default=False,
        help="With --stream: X times faster than real time [default: real time].")] = None,
    stream_format: Annotated[str, typer.Option(
        "--format", metavar="lines|motioncal|mavlink",
        callback=_one_of("lines", "motioncal", "mavlink"),
        help="With --stream: lines of t,ax,ay,az,gx,gy,gz, MotionCal's Raw: lines (counts, no "
             "time: capture them with --rate), or MAVLink HIGHRES_IMU messages.")] = "lines",
    acc_range: Annotated[float | None, typer.Option(
        "--acc-range", metavar="G", callback=positive, show_default=False,
        help="The accelerometer's range: it reads flat beyond it (a low-range part).")] = None,
    shake: Annotated[float, typer.Option(
        "--shake", metavar="G", callback=non_negative,
        help="A shake of this peak linear acceleration during every turn, which every "
             "accelerometer reads (past --acc-range: clipped).")] = 0.0,
    acc2: Annotated[float | None, typer.Option(
        "--acc2", metavar="G", callback=positive, show_default=False,
        help="A second accelerometer (columns a2x, a2y, a2z) of this range, with its own "
             "errors and noise, turned from the first; the truth in the truth file.")] = None,
    acc2_rotation: Annotated[float, typer.Option(
        "--acc2-rotation", metavar="DEG", callback=non_negative,
        help="--acc2: its rotation from the first, about an axis drawn.")] = 3.0,
    gyro2: Annotated[bool, typer.Option(
        "--gyro2", help="--acc2: a gyroscope in its IMU too (g2x, g2y, g2z).")] = False,
    temperature: Annotated[tuple[float, float] | None, typer.Option(
        "--temperature", metavar="START END", show_default=False,
        help="A temperature (column temp, deg C) from START to END over the session, which "
             "moves the biases (method.md M16).")] = None,
    temp_steps: Annotated[int, typer.Option(
        "--temp-steps", metavar="N", callback=non_negative,
        help="--temperature in N equal steps instead of a ramp.")] = 0,
    temp_acc_bias: Annotated[str | None, typer.Option(
        "--temp-acc-bias", metavar="X,Y,Z", show_default=False,
        help="--temperature: the accelerometer bias's slope, mg per deg C [default: a 2nd-order "
             "drift].")] = None,
    temp_acc_scale: Annotated[str | None, typer.Option(
        "--temp-acc-scale", metavar="X,Y,Z", show_default=False,
        help="--temperature: the accelerometer scales' slope, ppm per deg C [default: 0].")] = None,
    temp_gyro_bias: Annotated[str | None, typer.Option(
        "--temp-gyro-bias", metavar="X,Y,Z", show_default=False,
        help="--temperature: the gyroscope bias's slope, deg/s per deg C [default: a 2nd-order "
             "drift].")] = None,
    verbose: VerboseOpt = False,
) -> None:
    """Write a synthetic session with known parameters, and its truth as JSON."""
    if activity is not None:
        from imucal.cli.synth_everyday import synth_everyday

        synth_everyday(out, truth, activity, minutes=minutes, seed=seed, acc_rate=acc_rate,
                       acc_noise=acc_noise, gyro_noise=gyro_noise,
                       drifts=(drift_gyro_bias, drift_acc_bias, drift_acc_scale),
                       verbose=verbose)
        return
    if (drift_gyro_bias, drift_acc_bias, drift_acc_scale) != (None, None, None):
        raise usage_error("the --drift-* options shape everyday use: give --activity",
                          "'--drift-gyro-bias'")
    csv = out.suffix.lower() == ".csv"
    if (preamble or cut_last_line) and not csv:
        raise usage_error("--preamble and --cut-last-line shape a CSV: name OUT.csv", "'OUT'")
    if csv and gyro_rate not in (None, acc_rate):
        raise usage_error("a CSV holds one table: the gyroscope runs at the accelerometer's rate",
                          "'--gyro-rate'")
    if poses is not None and minutes is not None:
        raise usage_error("give either --poses or --minutes, not both", "'--minutes'")
    if mag_rate is not None and not csv:
        raise usage_error("a magnetometer is written in a CSV's mx, my, mz columns: name "
                          "OUT.csv", "'--mag-rate'")
    if mag_rate is not None and abs(acc_rate / mag_rate - round(acc_rate / mag_rate)) > 1e-9:
        raise usage_error("the magnetometer's rate must divide the accelerometer's (a CSV "
                          "holds it on the accelerometer's rows)", "'--mag-rate'")
    if mag_disturbance is not None and (mag_rate is None
                                        or not 0 <= mag_disturbance[0] < mag_disturbance[1]):
        raise usage_error("--mag-disturbance T0 T1 needs --mag-rate and 0 <= T0 < T1",
                          "'--mag-disturbance'")
    from imucal.cli.synth_triads import described, triad_kwargs

    extra = triad_kwargs(csv=csv, counts="counts" in (acc_unit, gyro_unit), acc_range=acc_range,
                         shake=shake, acc2=acc2, acc2_rotation=acc2_rotation, gyro2=gyro2,
                         temperature=temperature, temp_steps=temp_steps,
                         temp_acc_bias=temp_acc_bias, temp_acc_scale=temp_acc_scale,
                         temp_gyro_bias=temp_gyro_bias)
    if minutes is not None:
        # duration ~ init_still + n * still + (n - 1) * move (the durations vary by +-20 %)
        poses = max(2, round((minutes * 60.0 - init_still + move) / (still + move)))
    poses = 30 if poses is None else poses
    # After the full name: my.mat and my.csv each have their own truth, so a synth never
    # replaces a file the user did not name (my.truth.json was both's).
    truth = truth if truth is not None else out.with_name(out.name + ".truth.json")
    check_outputs([out, truth], [])
    progress = Progress(verbose)
    from imucal.io.export import write_session_csv, write_session_mat, write_truth
    from imucal.synth import make_session

    with progress.stage(f"generating {poses} poses"):
        sess, tr = make_session(poses=poses, seed=seed, still=still, move=move,
                                init_still=init_still, acc_rate=acc_rate, gyro_rate=gyro_rate,
                                acc_noise=acc_noise, gyro_noise=gyro_noise, gyro_drift=drift,
                                change_at=change_at, acc_unit=acc_unit, gyro_unit=gyro_unit,
                                mag_rate=mag_rate, mag_field=mag_field, mag_dip_deg=mag_dip,
                                mag_noise=mag_noise, mag_disturbance=mag_disturbance,
                                **extra)
    with progress.stage(f"writing {out}"):
        if csv:
            stated = {"sample_rate_hz": acc_rate, "init_still_s": init_still}
            write_session_csv(out, sess, gyro_unit=gyro_unit,
                              preamble=stated if preamble else None, cut_last_line=cut_last_line,
                              mag=mag_rate is not None, triads=bool(extra))
        else:
            write_session_mat(out, sess, gyro_unit=gyro_unit)
        write_truth(truth, tr)
    change = "" if tr.t_change is None else f", parameters change at {tr.t_change:.1f} s"
    change += described(extra)
    if tr.mag is not None:
        change += (f", magnetometer {len(sess.others[0].t)} samples at "
                   f"{fmt_rate(mag_rate)} (gauss)")
    import sys

    print(f"session         {poses} poses, {sess.duration:.1f} s, accelerometer "
          f"{len(sess.acc)} samples at {fmt_rate(sess.acc_rate)} ({acc_unit}), gyroscope "
          f"{len(sess.gyro)} samples at {fmt_rate(sess.gyro_rate)} ({gyro_unit}){change}\n"
          f"wrote {out}\nwrote {truth}", file=sys.stderr if stream == "-" else sys.stdout,
          flush=True)
    if stream is not None:
        from imucal.capture.send import stream_session

        stream_session(sess, stream, 1.0 if speed is None else speed, stream_format)


@app.command()
@shared_options(INPUT_OPTIONS, SETTING_OPTIONS)
def view(
    target: Annotated[Path, typer.Argument(
        metavar="SESSION|RUN.rrd", show_default=False,
        help="A recording to calibrate and show, or a saved .rrd to open.")],
    save: Annotated[str | None, typer.Option(
        "--save", metavar="FILE.rrd", help="Save the recording instead of opening a viewer.")
    ] = None,
    web: Annotated[bool, typer.Option("--web", help="Serve the web viewer.")] = False,
    port: Annotated[int | None, typer.Option(
        "--port", metavar="N", min=1, max=65535, show_default=False,
        help="Port of the web viewer [default: 9090, or a free one when 9090 is taken]; a "
             "port given must be free.")] = None,
    grpc_port: Annotated[int | None, typer.Option(
        "--grpc-port", metavar="N", min=1, max=65535, show_default=False,
        help="Port of the viewer's gRPC server [default: a free one]; a port given must be "
             "free.")] = None,
    bind: Annotated[str, typer.Option(
        "--bind", metavar="ADDR", callback=ip_address,
        help="Address the viewer's servers listen on (0.0.0.0: every interface, to be "
             "reached from other machines).")] = "127.0.0.1",
    options: dict[str, Any] = None,  # INPUT_OPTIONS and SETTING_OPTIONS
    verbose: Annotated[bool, typer.Option(
        "--verbose", "-v", help="Show the viewer's own log on the terminal.")] = False,
) -> int:
    """Calibrate a recording and show every step in Rerun (or open a saved .rrd).

    Without a display (and without --web) the recording is written to SESSION-STEM.rrd in the
    current directory instead (SESSION-STEM-1.rrd, -2, ... if that name is taken: a file
    imucal named itself never replaces another). The viewer's servers listen on 127.0.0.1
    unless --bind says otherwise; its own log is shown only with -v (a failure is one line).
    The native viewer needs a GPU or a software Vulkan renderer (Debian/Ubuntu:
    mesa-vulkan-drivers); the web viewer a browser.
    """
    settings = build_settings(**pick(options, SETTING_OPTIONS))
    check_magnitudes(settings)
    load_kw = load_kwargs(**pick(options, INPUT_OPTIONS))
    gyro = load_kw["gyro_path"]
    load_defaults = load_kwargs(**{name: default for name, _, default in INPUT_OPTIONS})
    load_options = {key: v for key, v in load_kw.items() if v != load_defaults[key]}
    overrides = {key: v for key, v in settings.items() if v != DEFAULTS[key]}
    check_inputs([target, gyro])
    if not target.exists():
        raise ImucalError("file not found", source=str(target))
    if save is not None:
        check_outputs([save], [target, gyro])
    with viewer_available():
        from viewer.app import show
    from imucal.cli.summary import result_line

    rc = show(str(target), save=save, web=web, port=port, grpc_port=grpc_port, bind=bind,
              verbose=verbose, load_options=load_options or None,
              on_result=lambda result: print(result_line(result), flush=True), **overrides)
    return int(rc or 0)
