"""The fleet's commands: ``batch`` (many recordings on a Dask cluster) and ``store`` (a
calibration store per device). Registered on the ``imucal`` app when imucal.cli loads.

Only the standard library and typer at module level (``imucal --help`` stays fast); dask,
numpy and polars are imported inside the commands.
"""

from __future__ import annotations

import functools
import sys
from pathlib import Path
from typing import Annotated, Any

import typer

from imucal.cli.commands import app
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
from imucal.cli.outputs import _isatty
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


@app.command()
@shared_options(INPUT_OPTIONS, SETTING_OPTIONS)
def batch(
    patterns: Annotated[list[str], typer.Argument(
        metavar="GLOB...", show_default=False,
        help="Session files or quoted glob patterns ('sessions/**/*.mat').")],
    out_dir: Annotated[Path, typer.Option(
        "--out-dir", metavar="DIR", show_default=False,
        help="Where each session's calib.json (DIR/DEVICE/SESSION.calib.json) and "
             "summary.parquet go.")],
    scheduler: Annotated[str | None, typer.Option(
        "--scheduler", metavar="tcp://HOST:PORT", show_default=False,
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
    options: dict[str, Any] = None,  # INPUT_OPTIONS and SETTING_OPTIONS
    verbose: VerboseOpt = False,
) -> int:
    """Calibrate many recordings on a Dask cluster: one calib.json each and a summary table.

    A session that fails is a row with its error; re-running skips sessions whose input
    (sha256), settings and spec are unchanged. Exit 1 when a session failed or broke the spec.
    """
    if options["gyro"] is not None:
        raise usage_error("--gyro names one file; in a batch each session file holds its "
                          "gyroscope", "'--gyro'")
    if workers is not None and scheduler is not None:
        raise usage_error("--workers sizes the LocalCluster; an existing cluster (--scheduler) "
                          "is used as it is", "'--workers'")
    settings = build_settings(**pick(options, SETTING_OPTIONS))
    load_kw = load_kwargs(**pick(options, INPUT_OPTIONS))
    files = _expand(patterns)
    if out_dir.exists() and not out_dir.is_dir():
        raise ImucalError("is a file; expected a directory", source=str(out_dir),
                          field="--out-dir")
    from imucal.fleet.batch import run_batch
    from imucal.fleet.spec import load_spec

    limits = load_spec(spec) if spec is not None else None
    tty = _isatty(sys.stderr)
    show = functools.partial(_progress_line, tty=tty) if verbose or tty else None
    report = run_batch(files, out_dir, load_kw=load_kw, settings=settings, scheduler=scheduler,
                       workers=workers, device_from=device_from, spec=limits, force=force,
                       progress=show)
    return _print_report(report, limits)


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
    if failed:
        lines.append("failed:")
        lines += [f"  - {r['error'] if r['path'] in r['error'] else r['path'] + ': ' + r['error']}"
                  for r in failed]
    if out_of_spec:
        lines.append("out of spec:")
        lines += [f"  - {r['device']}/{r['session']}: {'; '.join(r['spec_broken'])}"
                  for r in out_of_spec]
    if by["duplicate"]:
        lines.append("duplicates (same bytes, calibrated once):")
        lines += [f"  - {r['path']} = {r['duplicate_of']}" for r in by["duplicate"]]
    lines.append(f"wrote {report.summary}")
    print("\n".join(lines))
    return EXIT_SESSIONS_FAILED if failed or out_of_spec else 0
