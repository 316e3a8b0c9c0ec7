"""``imucal check`` and ``imucal refresh``: a stored calibration against a recording of
everyday use (method.md §10). Registered on the same typer ``app`` as the others; they parse
options, load, and call :mod:`imucal.inuse`.

``check`` exits 0 when the calibration holds, 1 when it drifted, 2 when the recording cannot
tell (and 1 too for bad input, as every command: the line on stderr says which)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from imucal.cli.app import app
from imucal.cli.options import (
    INPUT_OPTIONS,
    VerboseOpt,
    input_options,
    load_kwargs,
    pick,
    positive,
    shared_options,
)
from imucal.cli.outputs import Progress, check_inputs, check_outputs, viewer_available


def _limits() -> tuple[float, float]:
    """The limits declared once in imucal.inuse.limits (free of numpy), for the options'
    defaults; imported here, not at the top, as every CLI module keeps its imports light."""
    from imucal.inuse.limits import ACC_LIMIT_MG, GYRO_LIMIT_DEG_S

    return ACC_LIMIT_MG, GYRO_LIMIT_DEG_S


ACC_LIMIT_MG, GYRO_LIMIT_DEG_S = _limits()

CHECK_INPUT_OPTIONS = input_options("Check the accelerometer alone.")
CalibArg = Annotated[Path, typer.Argument(metavar="CALIB.json", show_default=False,
                                          help="Calibration file from 'imucal calibrate'.")]
RecordingArg = Annotated[Path, typer.Argument(
    metavar="RECORDING", show_default=False,
    help="A recording of ordinary use, in any format 'imucal calibrate' reads.")]
RrdOpt = Annotated[str | None, typer.Option(
    "--rrd", metavar="FILE.rrd", show_default=False,
    help="Also save a Rerun recording: the still moments on the recording's timeline, each "
         "figure over the recording against its stored value and band (and what refresh "
         "changed).")]


def _recording_saver(rrd: str | None):
    """The viewer's writer for ``--rrd`` (a missing rerun-sdk is one line, before any work)."""
    if rrd is None:
        return None
    with viewer_available():
        from viewer.inuse import save_check_recording
    return save_check_recording


def _load(calibration: Path, recording: Path, options: dict[str, Any], progress: Progress):
    """The calibration, its stored figures and contents, the recording (read in the units the
    calibration states where none is given), and notes on the units taken."""
    import imucal
    from imucal.io.calibration_file import recorded_units
    from imucal.io.inuse_file import read_for_check

    load_kw = load_kwargs(**pick(options, INPUT_OPTIONS))
    check_inputs([calibration, recording, load_kw["gyro_path"]])
    with progress.stage(f"reading {calibration.name}"):
        cal, stored, data = read_for_check(calibration)
        _, units = recorded_units(calibration)
    notes = []
    for key, unit in units.items():
        if load_kw[key] == "auto":  # a still gyroscope cannot tell rad/s from deg/s itself
            load_kw[key] = unit
            sensor = {"acc_unit": "accelerometer", "gyro_unit": "gyroscope"}[key]
            notes.append(f"{sensor} read in {unit}, as {calibration.name} states")
    with progress.stage(f"loading {recording.name}"):
        session = imucal.load_session(recording, **load_kw)
    return cal, stored, data, session, notes


@app.command("check")
@shared_options(CHECK_INPUT_OPTIONS)
def check_cmd(
    calibration: Annotated[Path, typer.Argument(
        metavar="CALIB.json", show_default=False,
        help="Calibration file from 'imucal calibrate' (with --moments-only: the recording).")],
    recording: Annotated[Path | None, typer.Argument(
        metavar="RECORDING", show_default=False,
        help="A recording of ordinary use, in any format 'imucal calibrate' reads.")] = None,
    moments_only: Annotated[bool, typer.Option(
        "--moments-only", help="Without a calibration: 'imucal check --moments-only "
        "RECORDING' lists the still moments found (the noise learned from the recording) and "
        "whether they would let check judge and refresh update; exit 0 enough, 2 not.")
    ] = False,
    as_json: Annotated[bool, typer.Option("--json", help="Print the figures as JSON.")] = False,
    acc_limit: Annotated[float, typer.Option(
        "--acc-limit", metavar="MG", callback=positive,
        help="The accelerometer drifted when its still-norm RMS is shown above this (or "
             "twice what the calibration leads one to expect, if more).")] = ACC_LIMIT_MG,
    gyro_limit: Annotated[float, typer.Option(
        "--gyro-limit", metavar="DEG/S", callback=positive,
        help="The gyroscope drifted when an axis' rate at rest is shown beyond this.")
    ] = GYRO_LIMIT_DEG_S,
    rrd: RrdOpt = None,
    options: dict[str, Any] = None,  # INPUT_OPTIONS
    verbose: VerboseOpt = False,
) -> int:
    """Does a calibration still hold? Judged from the still moments of a recording of
    ordinary use (method.md §10).

    Exit codes: 0 holds, 1 drifted (which parameters, by how much), 2 cannot tell (too few
    still moments or orientations); 1 also for bad input, with one line saying so. With
    --moments-only RECORDING, no calibration: the still moments and whether they would
    suffice (0 yes, 2 no).
    """
    if moments_only:
        return _moments_only(calibration, recording, as_json, rrd, options, verbose,
                             (acc_limit, gyro_limit))
    if recording is None:
        from imucal.cli.options import usage_error

        raise usage_error("give the calibration and the recording (or --moments-only "
                          "RECORDING)", "'RECORDING'")
    from imucal.io.atomic import Transaction

    tx = Transaction([rrd], inputs=[calibration, recording])  # checked before any work
    save = _recording_saver(rrd)
    progress = Progress(verbose)
    cal, stored, _, session, notes = _load(calibration, recording, options, progress)
    from imucal.inuse.check import check

    with progress.stage("finding still moments and judging"):
        result = check(cal, stored, session, acc_limit_mg=acc_limit,
                       gyro_limit_deg_s=gyro_limit)
    if save is not None:
        with tx, progress.stage(f"writing {rrd}"):
            with tx.writing(rrd) as tmp, open(tmp, "wb") as f:
                save(result, cal, session, f)
            tx.commit()
    if as_json:
        import json

        data = result.to_dict() | {"calibration": str(calibration),
                                   "recording": session.source}
        data["notes"] = notes + data["notes"] + list(session.notes)
        print(json.dumps(data, indent=2, allow_nan=False))
    else:
        print("\n".join(_check_lines(result, calibration, session, notes)
                        + ([f"wrote {rrd}"] if save is not None else [])))
    return result.exit_code


def _moments_only(recording: Path, extra: Path | None, as_json: bool, rrd: str | None,
                  options: dict[str, Any], verbose: bool, limits: tuple[float, float]) -> int:
    """``check --moments-only RECORDING``: imucal.inuse.survey, no calibration."""
    from imucal.cli.options import usage_error

    if extra is not None:
        raise usage_error("--moments-only takes the recording alone, no calibration",
                          "'RECORDING'")
    if rrd is not None or limits != (ACC_LIMIT_MG, GYRO_LIMIT_DEG_S):
        raise usage_error("--rrd, --acc-limit and --gyro-limit judge a calibration: not with "
                          "--moments-only", "'--moments-only'")
    import imucal
    from imucal.inuse.survey import survey

    load_kw = load_kwargs(**pick(options, INPUT_OPTIONS))
    check_inputs([recording, load_kw["gyro_path"]])
    progress = Progress(verbose)
    with progress.stage(f"loading {recording.name}"):
        session = imucal.load_session(recording, **load_kw)
    with progress.stage("finding still moments"):
        result = survey(session)
    if as_json:
        import json

        data = result.to_dict() | {"recording": session.source}
        data["notes"] += list(session.notes)
        print(json.dumps(data, indent=2, allow_nan=False))
    else:
        print("\n".join([f"recording       {session.source}"] + result.lines()
                        + [f"  - {n}" for n in session.notes]))
    return result.exit_code


def _check_lines(result, calibration: Path, session, notes: list[str]) -> list[str]:
    m = result.moments
    lines = [f"verdict         {result.level}: {result.reason}",
             f"calibration     {calibration}"
             + (f" (segment {result.segment}, the last)" if result.segment > 1 else ""),
             f"recording       {session.source}: {session.duration:.1f} s",
             f"still moments   {m.count}, {float(m.durations.sum()) if m.count else 0.0:.1f} s "
             f"in all, {m.orientations} orientation(s); detector: window {m.window}, shortest "
             f"{m.min_len} samples, k {m.k:g} on {m.level_from}"]
    for p in result.parts:
        lines.append(f"{p.sensor:<15} {p.level}: {p.reason}")
    extra = notes + list(result.notes) + list(session.notes)
    if extra:
        lines.append("notes:")
        lines += [f"  - {n}" for n in extra]
    return lines


@app.command("refresh")
@shared_options(CHECK_INPUT_OPTIONS)
def refresh_cmd(
    calibration: CalibArg,
    recording: RecordingArg,
    out: Annotated[str, typer.Option("--out", "-o", metavar="NEW.json", show_default=False,
                                     help="The refreshed calibration file to write.")],
    store: Annotated[Path | None, typer.Option(
        "--store", metavar="DIR", show_default=False,
        help="Also add it to this calibration store as a new version of its device (the "
             "calibration's own device, or --device); both written or neither.")] = None,
    device: Annotated[str | None, typer.Option(
        "--device", metavar="ID", show_default=False,
        help="With --store: the device's id [default: the calibration's].")] = None,
    rrd: RrdOpt = None,
    options: dict[str, Any] = None,  # INPUT_OPTIONS
    verbose: VerboseOpt = False,
) -> int:
    """Update what a recording of ordinary use determines: the gyroscope's bias from its
    still moments, the accelerometer's bias and scale on each axis the moments cover at 0.3 g
    on both sides; every other parameter stays exactly as stored (method.md §10).

    Exit codes: 0 written; 2 the recording determines nothing (nothing written); 1 bad input.
    NEW.json and the --rrd recording are written together or not at all.
    """
    if device is not None and store is None:
        from imucal.cli.options import usage_error

        raise usage_error("--device names the device in the store: give --store", "'--device'")
    check_outputs([out, rrd], [calibration, recording])  # checked before any work
    save = _recording_saver(rrd)
    progress = Progress(verbose)
    cal, stored, data, session, notes = _load(calibration, recording, options, progress)
    from imucal.inuse.refresh import refresh
    from imucal.io.inuse_file import file_sha256, refreshed_dict, write_refreshed

    with progress.stage("finding still moments and refreshing"):
        result = refresh(cal, stored, session)
    lines = [f"check           {result.check.level}: {result.check.reason}"]
    if not result.determined:
        lines.append("refresh         nothing determined: "
                     + "; ".join(result.kept) + "; nothing written")
        print("\n".join(lines))
        return 2
    new = refreshed_dict(data, result, calibration=str(calibration),
                         calibration_sha256=file_sha256(calibration),
                         recording=session.source, recording_sha256=session.sha256
                         or file_sha256(recording))

    def write_rrd(tmp: Path) -> None:
        with progress.stage(f"writing {rrd}"), open(tmp, "wb") as f:
            save(result.check, cal, session, f, result)

    write_also = write_rrd if save is not None else None
    with progress.stage(f"writing {out}"):
        if store is None:  # NEW.json and the --rrd recording: both or neither
            from imucal.io.atomic import Transaction

            with Transaction([out, rrd], inputs=[calibration, recording]) as tx:
                with tx.writing(out) as tmp:
                    write_refreshed(tmp, new)
                if write_also is not None:
                    with tx.writing(rrd) as tmp:
                        write_also(tmp)
                tx.commit()
        else:  # imucal.fleet.refresh_store: --out, --rrd and the store's new version, or none
            from imucal.fleet.refresh_store import write_with_store

            version = write_with_store(out, new, store=store, device=device,
                                       calibration=calibration, recording=recording,
                                       inputs=[calibration, recording], rrd=rrd,
                                       write_rrd=write_also)
    for c in result.changed:
        lines.append(f"changed         {c.sensor} {c.parameter}: {c.stored:.6g} -> "
                     f"{c.value:.6g} ({c.change:+.3g} {c.unit}, std error {c.std_error:.2g})")
    lines += [f"kept            {k}" for k in result.kept]
    if result.norm_before_mg is not None:
        lines.append(f"still-norm      {result.norm_before_mg:.2f} mg stored -> "
                     f"{result.norm_after_mg:.2f} mg refreshed, over "
                     f"{result.check.moments.count} moments")
    lines += [f"  - {n}" for n in notes]
    lines.append(f"wrote {out}")
    lines += [f"wrote {rrd}"] if save is not None else []
    if store is not None:
        lines.append(f"{'already stored as' if version.already else 'stored'} {version.path} "
                     f"(device {version.device}, the recording's time)")
    print("\n".join(lines))
    return 0
