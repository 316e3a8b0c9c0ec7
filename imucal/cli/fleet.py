"""The fleet's commands: ``batch`` (many recordings on a Dask cluster), ``store add | list |
get`` (a calibration store per device), ``drift`` (a device's parameters over time) and
``fleet report`` (every parameter across the fleet, outliers flagged). Registered on the
``imucal`` app when imucal.cli loads.

Only the standard library and typer at module level (``imucal --help`` stays fast); dask,
numpy and polars are imported inside the commands.
"""

from __future__ import annotations

import functools
import sys
from pathlib import Path
from typing import Annotated, Any

import typer

from imucal.cli.app import app
from imucal.cli.options import (
    INPUT_OPTIONS,
    SETTING_OPTIONS,
    VerboseOpt,
    at_least,
    build_settings,
    load_kwargs,
    pick,
    shared_options,
    usage_error,
)
from imucal.cli.outputs import _isatty, check_outputs, viewer_available
from imucal.errors import ImucalError

EXIT_SESSIONS_FAILED = 1


def _expand(patterns: list[str]) -> list[Path]:
    """Files matched by the glob patterns (``**`` recurses), each once, sorted; a pattern the
    shell already expanded is a plain path."""
    import glob

    found: dict[str, Path] = {}
    for pattern in patterns:
        matches = glob.glob(pattern, recursive=True) if glob.has_magic(pattern) else [pattern]
        for m in matches:
            p = Path(m)
            if p.is_file():
                found.setdefault(str(p.resolve()), p)
            elif not glob.has_magic(pattern):
                raise ImucalError("file not found" if not p.exists() else
                                  "is a directory; expected a session file or a glob pattern",
                                  source=m)
    if not found:
        raise ImucalError("no file matches", source=" ".join(patterns), field="GLOB")
    return sorted(found.values())


def _progress_line(counts, tty: bool) -> None:
    """One line, rewritten in place on a terminal; a line per session in a log (-v)."""
    eta = "n/a" if counts.eta is None else f"{counts.eta:.0f} s"
    sys.stderr.write(f"{chr(13) if tty else ''}done {counts.done} / failed {counts.failed} / "
                     f"skipped {counts.skipped} / left {counts.left}, {counts.rate:.2f} "
                     f"sessions/s, ETA {eta}   ")
    if counts.left == 0 or not tty:
        sys.stderr.write("\n")
    sys.stderr.flush()


# A --gyro ending so names a file (a log's stream names a topic, an IMU, a dataset).
_DATA_SUFFIXES = {".mat", ".csv", ".tsv", ".txt", ".dat", ".log", ".parquet", ".h5", ".hdf5"}


def _scheduler_address(value: str | None) -> str | None:
    """--scheduler as Dask reads an address, or a usage error saying what is expected (was
    an internal error, exit 3, for 'notanaddress')."""
    if value is None:
        return None
    from imucal.fleet.scheduler import split_address

    try:
        split_address(value)
    except ValueError as e:
        raise typer.BadParameter(str(e)) from None
    return value


@app.command()
@shared_options(INPUT_OPTIONS, SETTING_OPTIONS)
def batch(
    patterns: Annotated[list[str], typer.Argument(
        metavar="GLOB...", show_default=False,
        help="Session files or quoted glob patterns ('sessions/**/*.mat').")],
    out_dir: Annotated[Path | None, typer.Option(
        "--out-dir", metavar="DIR", show_default=False,
        help="Where each session's calib.json (DIR/DEVICE/SESSION.calib.json) and "
             "summary.parquet go (required unless --check).")] = None,
    scheduler: Annotated[str | None, typer.Option(
        "--scheduler", metavar="tcp://HOST:PORT", show_default=False,
        callback=_scheduler_address,
        help="An existing Dask scheduler, used as it is [default: a LocalCluster on "
             "127.0.0.1].")] = None,
    workers: Annotated[int | None, typer.Option(
        "--workers", metavar="N", callback=at_least(1), show_default=False,
        help="Worker processes of the LocalCluster [default: one per core, at most one per "
             "session].")] = None,
    device_from: Annotated[str | None, typer.Option(
        "--device-from", metavar="PATTERN", show_default=False,
        help="Device id (and date) from the path, e.g. '{device}/{date}_*.csv' "
             "[default: the file's parent folder].")] = None,
    spec: Annotated[Path | None, typer.Option(
        "--spec", metavar="LIMITS.toml", show_default=False,
        help="Limits each session passes or fails (bias, scale, misalignment, errors).")
    ] = None,
    force: Annotated[bool, typer.Option(
        "--force", help="Redo sessions whose input and settings are unchanged.")] = False,
    store: Annotated[Path | None, typer.Option(
        "--store", metavar="DIR", show_default=False,
        help="Also add each calibration to this calibration store (see 'imucal store').")
    ] = None,
    check_store: Annotated[Path | None, typer.Option(
        "--check", metavar="CALIB_STORE", show_default=False,
        help="Instead of calibrating: check each recording (imucal check) against its "
             "device's latest calibration in this store; a table per device.")] = None,
    as_json: Annotated[bool, typer.Option(
        "--json", help="With --check: print the figures as JSON.")] = False,
    options: dict[str, Any] = None,  # INPUT_OPTIONS and SETTING_OPTIONS
    verbose: VerboseOpt = False,
) -> int:
    """Calibrate many recordings on a Dask cluster: one calib.json each and a summary table.

    A session that fails is a row with its error; re-running skips sessions whose input
    (sha256), settings and spec are unchanged. Each session's verdict (good, usable with
    caveats, not usable) is a column of the table. Exit 1 when a session failed, broke the spec
    or is not usable.

    With --check CALIB_STORE: each recording of ordinary use is checked against its device's
    latest stored calibration (method.md §10), a device being drifted when one of its
    recordings says so, else holds when one does, else cannot tell. Exit 1 when a device
    drifted or a recording failed (bad file, no calibration stored for its device), else 2
    when a device cannot tell, else 0.
    """
    if check_store is not None:
        return _batch_check(patterns, check_store, options, scheduler=scheduler,
                            workers=workers, device_from=device_from, as_json=as_json,
                            verbose=verbose, refused={"--out-dir": out_dir, "--spec": spec,
                                                      "--store": store, "--force": force})
    if out_dir is None:
        raise usage_error("--out-dir is needed (unless --check)", "'--out-dir'")
    if as_json:
        raise usage_error("--json goes with --check", "'--json'")
    gyro = options["gyro"]
    if gyro is not None and (Path(gyro).exists() or Path(gyro).suffix.lower() in _DATA_SUFFIXES):
        raise usage_error("--gyro names one file; in a batch each session file holds its "
                          "gyroscope (a log's gyroscope stream may be named)", "'--gyro'")
    if workers is not None and scheduler is not None:
        raise usage_error("--workers sizes the LocalCluster; an existing cluster (--scheduler) "
                          "is used as it is", "'--workers'")
    from imucal.fleet.batch import require_dask, run_batch

    require_dask()
    settings = build_settings(**pick(options, SETTING_OPTIONS))
    load_kw = load_kwargs(**pick(options, INPUT_OPTIONS))
    files = _expand(patterns)
    for folder, option in ((out_dir, "--out-dir"), (store, "--store")):
        if folder is not None and folder.exists() and not folder.is_dir():
            raise ImucalError("is a file; expected a directory", source=str(folder),
                              field=option)
    from imucal.fleet.spec import load_spec

    limits = load_spec(spec) if spec is not None else None
    tty = _isatty(sys.stderr)
    show = functools.partial(_progress_line, tty=tty) if verbose or tty else None
    report = run_batch(files, out_dir, load_kw=load_kw, settings=settings, scheduler=scheduler,
                       workers=workers, device_from=device_from, spec=limits, force=force,
                       progress=show, store=store)
    return _print_report(report, limits)


def _batch_check(patterns: list[str], check_store: Path, options: dict[str, Any], *,
                 scheduler: str | None, workers: int | None, device_from: str | None,
                 as_json: bool, verbose: bool, refused: dict[str, Any]) -> int:
    """``batch --check``: imucal.fleet.check on the cluster, a table or JSON."""
    for option, value in refused.items():
        if value:
            raise usage_error(f"{option} calibrates; --check only checks", f"'{option}'")
    if workers is not None and scheduler is not None:
        raise usage_error("--workers sizes the LocalCluster; an existing cluster (--scheduler) "
                          "is used as it is", "'--workers'")
    from imucal.fleet.batch import require_dask
    from imucal.fleet.check import check_lines, run_check
    from imucal.inuse.limits import ACC_LIMIT_MG, GYRO_LIMIT_DEG_S

    require_dask()
    load_kw = load_kwargs(**pick(options, INPUT_OPTIONS))
    if load_kw["gyro_path"] is not None:
        raise usage_error("--gyro names one file; in a batch each session file holds its "
                          "gyroscope", "'--gyro'")
    files = _expand(patterns)
    tty = _isatty(sys.stderr)
    show = functools.partial(_progress_line, tty=tty) if verbose or tty else None
    report = run_check(files, check_store, load_kw=load_kw, acc_limit_mg=ACC_LIMIT_MG,
                       gyro_limit_deg_s=GYRO_LIMIT_DEG_S, scheduler=scheduler,
                       workers=workers, device_from=device_from, progress=show)
    if as_json:
        import json

        print(json.dumps(report.to_dict(), indent=2, allow_nan=False, default=str))
    else:
        print("\n".join(check_lines(report)))
    return report.exit_code


def _print_report(report, limits) -> int:
    rows = report.rows
    by = {s: [r for r in rows if r["status"] == s] for s in ("ok", "failed", "error",
                                                                 "duplicate")}
    c = report.counts
    how = sorted({r["device_from"] for r in rows if r["device_from"]})
    lines = [f"cluster         {report.cluster}",
             f"sessions        {len(rows)}: {c.done} calibrated, {c.failed} failed, "
             f"{c.skipped} skipped ({len(by['duplicate'])} duplicate)",
             f"device ids      from the {', '.join(how) or 'n/a'}"]
    failed = by["failed"] + by["error"]
    out_of_spec = [r for r in rows if r["spec_pass"] is False and r["status"] == "ok"]
    if limits is not None:
        judged = [r for r in rows if r["spec_pass"] is not None and r["status"] == "ok"]
        lines.append(f"spec            {limits.source}: {len(judged) - len(out_of_spec)} pass, "
                     f"{len(out_of_spec)} fail")
    ok = by["ok"]
    levels = [r.get("verdict") for r in ok]
    not_usable = [r for r in ok if r.get("verdict") == "not usable"]
    if any(levels):
        lines.append(f"verdict         {levels.count('good')} good, "
                     f"{levels.count('usable with caveats')} usable with caveats, "
                     f"{len(not_usable)} not usable")
    if not_usable:
        lines.append("not usable:")
        lines += [f"  - {r['device']}/{r['session']}: {r['verdict_reason']}; next: "
                  f"{r['verdict_next']}" for r in not_usable]
    if failed:
        lines.append("failed:")
        lines += [f"  - {r['error'] if r['path'] in r['error'] else r['path'] + ': ' + r['error']}"
                  for r in failed]
    if out_of_spec:
        lines.append("out of spec:")
        # a spec fails what it cannot judge too (imucal.fleet.spec): say which limits
        lines += [f"  - {r['device']}/{r['session']}: " + "; ".join(
            list(r["spec_broken"] or []) + [f"{k}: cannot be judged on this session"
                                            for k in r.get("spec_unchecked") or []])
                  for r in out_of_spec]
    if by["duplicate"]:
        lines.append("duplicates (same bytes, calibrated once):")
        lines += [f"  - {r['path']} = {r['duplicate_of']}" for r in by["duplicate"]]
    stored = report.stored
    if stored is not None:
        lines.append(f"store           {stored.store}: {stored.added} added, {stored.already} "
                     f"already there, {len(stored.failed)} not stored")
        lines += [f"  - not stored: {f}" for f in stored.failed]
    lines.append(f"wrote {report.summary}")
    print("\n".join(lines))
    bad = failed or out_of_spec or not_usable or (stored and stored.failed)
    return EXIT_SESSIONS_FAILED if bad else 0



# --- the calibration store -----------------------------------------------------------------------

store_app = typer.Typer(
    name="store", no_args_is_help=True, add_completion=False, rich_markup_mode=None,
    help="A calibration store per device: a folder of calib.json files (STORE/DEVICE/"
         "YYYY-MM-DDTHHMMSSZ.calib.json, the source of truth) and a Parquet index rebuilt "
         "from it.")
fleet_app = typer.Typer(name="fleet", no_args_is_help=True, add_completion=False,
                        rich_markup_mode=None, help="Reports across a fleet of devices.")
app.add_typer(store_app, name="store")
app.add_typer(fleet_app, name="fleet")

StoreOpt = Annotated[Path, typer.Option(
    "--store", metavar="DIR", envvar="IMUCAL_STORE", show_default=False,
    help="The calibration store's folder (or $IMUCAL_STORE).")]
DeviceOpt = Annotated[str, typer.Option("--device", metavar="ID", show_default=False,
                                        help="The device's id (its folder in the store).")]
AtOpt = Annotated[str | None, typer.Option(
    "--at", metavar="TIME", show_default=False,
    help="The calibration in force at this time (2024-05-01, 2024-05-01T12:30:00Z; UTC "
         "unless it says) [default: now].")]
RrdOpt = Annotated[Path | None, typer.Option(
    "--rrd", metavar="FILE.rrd", show_default=False, help="Also write a Rerun recording.")]


def _warn(message: str) -> None:
    sys.stderr.write(f"imucal: warning: {message}\n")


def _existing_store(store: Path) -> Path:
    if not store.is_dir():
        raise ImucalError("no calibration store here (the folder does not exist)",
                          source=str(store), field="--store")
    return store


@store_app.command("add")
def store_add(
    calib: Annotated[Path, typer.Argument(metavar="CALIB.json", show_default=False,
                                          help="A calibration file (imucal calibrate, batch).")],
    store: StoreOpt,
    device: Annotated[str | None, typer.Option(
        "--device", metavar="ID", show_default=False,
        help="The device's id [default: the file's 'device', which imucal batch writes].")
    ] = None,
    when: Annotated[str | None, typer.Option(
        "--when", metavar="TIME", show_default=False,
        help="When the unit was calibrated [default: the file's recorded_at, else its "
             "calibrated_at, else its modification time; the store says which].")] = None,
) -> int:
    """Add a calibration to the store, under its device and time (atomic; safe beside other
    adds). The same calibration at the same time is stored once."""
    from imucal.fleet import store as st

    at = st.parse_when(when, "--when") if when is not None else None
    dev = st.device_id(device) if device is not None else None
    added = st.add(store, calib, dev, at)
    verb = "already stored as" if added.already else "stored"
    print(f"{verb} {added.path} (device {added.device}, calibrated_at "
          f"{st.iso(added.calibrated_at)} from {added.when_from})")
    return 0


@store_app.command("list")
def store_list(store: StoreOpt, device: Annotated[str | None, typer.Option(
        "--device", metavar="ID", show_default=False, help="Only this device.")] = None
               ) -> int:
    """List the stored calibrations, oldest first per device."""
    from imucal.fleet import store as st

    rows = st.calibrations(_existing_store(store), st.device_id(device) if device else None)
    for problem in st.problems(store):
        _warn(problem)
    if not rows:
        _warn(f"{store}: no calibrations stored")
        return 0
    print("\n".join(st.list_lines(rows)))
    return 0


@store_app.command("get")
def store_get(
    store: StoreOpt, device: DeviceOpt, at: AtOpt = None,
    out: Annotated[Path | None, typer.Option(
        "--out", "-o", metavar="CALIB.json", show_default=False,
        help="Copy the calibration here [default: print its path].")] = None,
    max_age: Annotated[str, typer.Option(
        "--max-age", metavar="AGE",
        help="Warn when the calibration is older than this at TIME (s, m, h, d, w).")] = "90d",
) -> int:
    """The newest calibration of a device at or before a time: its path, or a copy of it."""
    from imucal.fleet import store as st

    when = st.parse_when(at, "--at") if at is not None else None
    limit = st.parse_age(max_age)
    if out is not None:
        check_outputs([out], [])
    picked = st.get(_existing_store(store), st.device_id(device), when, limit)
    if picked.too_old:
        _warn(f"the calibration of {device} in force at {st.iso(picked.at)} is "
              f"{st.describe_age(picked.age)} old, older than --max-age {max_age} "
              f"({picked.path})")
    if out is None:
        print(picked.path)
        return 0
    from imucal.io.atomic import write_text_atomic

    write_text_atomic(out, picked.path.read_text(encoding="utf-8"))
    print(f"wrote {out} (device {device}, calibrated_at "
          f"{st.iso(picked.row['calibrated_at'])}, {st.describe_age(picked.age)} before "
          f"{st.iso(picked.at)}; {picked.path})")
    return 0


# --- drift and the fleet report ------------------------------------------------------------------


@app.command()
def drift(
    device: Annotated[list[str], typer.Option(
        "--device", metavar="ID", show_default=False,
        help="The device (repeat for several in one recording).")],
    store: StoreOpt, rrd: RrdOpt = None,
) -> int:
    """How each parameter of a device moves over its calibrations: a table (and a recording
    on a 'calibrated_at' timeline)."""
    from imucal.fleet import store as st
    from imucal.fleet.drift import device_drift, drift_lines

    if rrd is not None:
        check_outputs([rrd], [])
    ids = [st.device_id(d) for d in device]
    drifts = [device_drift(d, st.calibrations(_existing_store(store), d)) for d in ids]
    print("\n\n".join("\n".join(drift_lines(d)) for d in drifts))
    if rrd is not None:
        with viewer_available():
            from viewer.fleet import save_drift
        save_drift(drifts, rrd)
        print(f"wrote {rrd}")
    return 0


@fleet_app.command("report")
def fleet_report(
    store: Annotated[Path, typer.Argument(metavar="STORE", show_default=False,
                                          help="The calibration store's folder.")],
    rrd: RrdOpt = None, at: AtOpt = None,
) -> int:
    """Every parameter across the fleet (the newest calibration of each device), with the
    units whose robust z-score exceeds 3.5 flagged (with 3 or 4 units, Dixon's Q at 99 %)."""
    from imucal.fleet import store as st
    from imucal.fleet.drift import fleet_lines
    from imucal.fleet.drift import fleet_report as report_of

    when = st.parse_when(at, "--at") if at is not None else None
    if rrd is not None:
        check_outputs([rrd], [])
    rows = st.calibrations(_existing_store(store))
    if not rows:
        raise ImucalError("no calibrations stored", source=str(store))
    rep = report_of(rows, when)
    print("\n".join(fleet_lines(rep)))
    if rrd is not None:
        with viewer_available():
            from viewer.fleet import save_fleet_report
        save_fleet_report(rep, rrd)
        print(f"wrote {rrd}")
    return 0
