"""The commands: calibrate, apply, synth, view. Each parses its options and calls the core
(and, for --rrd and view, the viewer)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from imucal.cli.options import (
    ACC_UNITS,
    DEFAULTS,
    GYRO_UNITS,
    INPUT_OPTIONS,
    SETTING_OPTIONS,
    SessionArg,
    VerboseOpt,
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

app = typer.Typer(
    name="imucal",
    help="Calibrate an IMU's accelerometer and gyroscope from an ordinary recording "
         "(still poses with turns between them).",
    add_completion=True,  # --install-completion, --show-completion (typer's)
    no_args_is_help=True,
    rich_markup_mode=None,
    pretty_exceptions_enable=False,
    context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100},
)



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
    options: dict[str, Any] = None,  # INPUT_OPTIONS and SETTING_OPTIONS
    verbose: VerboseOpt = False,
) -> None:
    """Calibrate a recording and write the calibration file (and optionally more).

    Every output is written to a temporary file and renamed into place only when all are
    complete: a failed or interrupted run changes no file.
    """
    settings = build_settings(**pick(options, SETTING_OPTIONS))
    check_magnitudes(settings)
    load_kw = load_kwargs(**pick(options, INPUT_OPTIONS))
    inputs = [session, load_kw["gyro_path"]]
    check_inputs(inputs)
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
        with progress.stage(f"calibrating {len(sess.acc)} samples (detect, group, fit)"):
            result = imucal.calibrate(sess, **settings)
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
    print_summary(result, written)
    if tx.removed:
        print("\n".join(removed_lines(tx.removed, result.calibrated)))


def _sidecar(table: str | None) -> Path | None:
    if table is None or Path(table).suffix.lower() == ".mat":
        return None
    return gyro_sidecar(Path(table))


def _owned(side: Path | None, table: str | None) -> dict[Path, str]:
    """The sidecar is a name the user did not give: imucal replaces or removes only a sidecar
    it wrote itself (imucal.io.atomic, owned)."""
    return {} if side is None else {side: f"the gyroscope table of {table}"}


@app.command()
@shared_options(INPUT_OPTIONS)
def apply(
    calibration: Annotated[Path, typer.Argument(metavar="CALIB.json", show_default=False,
                                                help="Calibration file from 'imucal calibrate'.")],
    session: SessionArg,
    out: Annotated[str, typer.Option(
        "--out", "-o", metavar="OUT.parquet|.csv|.mat", show_default=False,
        help="Calibrated signals to write; the format follows the name.")],
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
            sess = imucal.load_session(session, **load_kw)
        with progress.stage("applying"):
            signals = cal.apply(sess)
        with progress.stage(f"writing {out}"):
            write_signals(tx, out, signals)
        tx.commit()
    import numpy as np

    norm = signals.acc_norm
    lines = [f"session         {sess.source}: {sess.duration:.1f} s, accelerometer "
             f"{len(sess.acc)} samples ({sess.acc_unit}), "
             + (f"gyroscope {len(sess.gyro)} samples ({sess.gyro_unit})" if sess.has_gyro
                else "no gyroscope"),
             f"calibration     {calibration}: {len(cal.segments)} segment(s)",
             f"output          accelerometer in {signals.acc_unit} (median |a| "
             f"{float(np.median(norm)):.5g}, |g| = {cal.g:g})"
             + (", gyroscope in rad/s" if signals.gyro is not None else "")]
    if sess.has_gyro and signals.gyro is None:
        lines.append("warnings:\n  - the calibration has no gyroscope model: gyroscope not "
                     "written")
    if sess.notes:
        lines.append("notes:")
        lines += [f"  - {n}" for n in sess.notes]
    lines += [f"wrote {w}" for w in written_tables(Path(out), signals)]
    lines += removed_lines(tx.removed, signals)
    print("\n".join(lines))


@app.command()
def synth(
    out: Annotated[Path, typer.Argument(metavar="OUT.mat|OUT.csv", show_default=False,
                                        help="Session file to write (MATLAB v5, or CSV).")],
    truth: Annotated[Path | None, typer.Option(
        "--truth", metavar="PATH", show_default=False,
        help="Where to write the true parameters [default: OUT.truth.json].")] = None,
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
    verbose: VerboseOpt = False,
) -> None:
    """Write a synthetic session with known parameters, and its truth as JSON."""
    csv = out.suffix.lower() == ".csv"
    if (preamble or cut_last_line) and not csv:
        raise usage_error("--preamble and --cut-last-line shape a CSV: name OUT.csv", "'OUT'")
    if csv and gyro_rate not in (None, acc_rate):
        raise usage_error("a CSV holds one table: the gyroscope runs at the accelerometer's rate",
                          "'--gyro-rate'")
    if poses is not None and minutes is not None:
        raise usage_error("give either --poses or --minutes, not both", "'--minutes'")
    if minutes is not None:
        # duration ~ init_still + n * still + (n - 1) * move (the durations vary by +-20 %)
        poses = max(2, round((minutes * 60.0 - init_still + move) / (still + move)))
    poses = 30 if poses is None else poses
    truth = truth if truth is not None else out.with_suffix(".truth.json")
    check_outputs([out, truth], [])
    progress = Progress(verbose)
    from imucal.io.export import write_session_csv, write_session_mat, write_truth
    from imucal.synth import make_session

    with progress.stage(f"generating {poses} poses"):
        sess, tr = make_session(poses=poses, seed=seed, still=still, move=move,
                                init_still=init_still, acc_rate=acc_rate, gyro_rate=gyro_rate,
                                acc_noise=acc_noise, gyro_noise=gyro_noise, gyro_drift=drift,
                                change_at=change_at, acc_unit=acc_unit, gyro_unit=gyro_unit)
    with progress.stage(f"writing {out}"):
        if csv:
            stated = {"sample_rate_hz": acc_rate, "init_still_s": init_still}
            write_session_csv(out, sess, gyro_unit=gyro_unit,
                              preamble=stated if preamble else None, cut_last_line=cut_last_line)
        else:
            write_session_mat(out, sess, gyro_unit=gyro_unit)
        write_truth(truth, tr)
    change = "" if tr.t_change is None else f", parameters change at {tr.t_change:.1f} s"
    print(f"session         {poses} poses, {sess.duration:.1f} s, accelerometer "
          f"{len(sess.acc)} samples at {fmt_rate(sess.acc_rate)} ({acc_unit}), gyroscope "
          f"{len(sess.gyro)} samples at {fmt_rate(sess.gyro_rate)} ({gyro_unit}){change}\n"
          f"wrote {out}\nwrote {truth}")


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
    rc = show(str(target), save=save, web=web, port=port, grpc_port=grpc_port, bind=bind,
              verbose=verbose, load_options=load_options or None, **overrides)
    return int(rc or 0)


def print_version(ctx: typer.Context, value: bool) -> None:
    """``--version``: the program's name and :data:`imucal.__version__` (the package's)."""
    if value and not ctx.resilient_parsing:
        import imucal

        print(f"{ctx.find_root().info_name or 'imucal'} {imucal.__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: Annotated[bool, typer.Option("--version", callback=print_version, is_eager=True,
                                          help="Show the version and exit.")] = False,
) -> None:
    """Calibrate an IMU's accelerometer and gyroscope from an ordinary recording.

    Exit codes: 0 success, 1 a problem with the input, files or settings, 2 a usage error,
    3 an internal error, 130 interrupted.
    """
