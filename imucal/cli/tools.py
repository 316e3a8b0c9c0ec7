"""The commands that take a calibration elsewhere: ``export`` (to the formats other tools read)
and ``noise`` (the sensor's noise figures from a long still recording). Registered on the same
typer ``app`` as the others; like them they parse options and call the core."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from imucal.cli.app import app
from imucal.cli.options import (
    INPUT_OPTIONS,
    INSPECT_INPUT_OPTIONS,
    NOISE_INPUT_OPTIONS,
    VerboseOpt,
    at_least,
    load_kwargs,
    pick,
    shared_options,
)
from imucal.cli.outputs import Progress, check_outputs, fmt, viewer_available
from imucal.errors import ImucalError

FORMAT_NAMES = ("imu_tk", "fusion", "kalibr", "px4", "ardupilot", "c", "c_runtime", "json",
                "yaml")


def _format(value: str) -> str:
    v = value.strip().lower().replace("-", "_")
    v = {"imutk": "imu_tk", "x_io": "fusion", "h": "c", "yml": "yaml", "ap": "ardupilot"}.get(v, v)
    if v not in FORMAT_NAMES:
        raise typer.BadParameter(f"expected one of {', '.join(FORMAT_NAMES)}, got {value!r}")
    return v


@app.command("export")
def export_cmd(
    calibration: Annotated[Path, typer.Argument(metavar="CALIB.json", show_default=False,
                                                help="Calibration file from 'imucal calibrate'.")],
    to: Annotated[str, typer.Option(
        "--to", metavar="|".join(FORMAT_NAMES), callback=_format, show_default=False,
        help="Target format.")],
    out: Annotated[Path | None, typer.Option(
        "--out", "-o", metavar="FILE", show_default=False,
        help="File to write [default: beside CALIB.json, named after it and the format; "
             "imu_tk writes FILE_acc.calib and FILE_gyro.calib; c_runtime takes a directory and "
             "writes imucal_runtime.h and imucal_runtime.c in it].")] = None,
    segment: Annotated[int | None, typer.Option(
        "--segment", metavar="N", callback=at_least(1), show_default=False,
        help="Which segment (1-based) a one-model format takes [required when there are "
             "several].")] = None,
    noise: Annotated[Path | None, typer.Option(
        "--noise", metavar="NOISE.json", show_default=False,
        help="Noise figures from 'imucal noise --out' instead of the calibration's own "
             "(kalibr, json, yaml).")] = None,
) -> None:
    """Write a calibration in a format firmware and robotics tools read, and say what the
    conversion keeps or loses."""
    from imucal.io.exports import default_output, export

    target = out if out is not None else default_output(calibration, to)
    if to != "c_runtime":  # c_runtime's --out is a directory, its files checked as written
        check_outputs([target], [calibration, noise])
    result = export(calibration, to, target, segment=segment, noise=noise)
    lines = [f"export          {to}: {calibration}"]
    verdict = _verdict_of(calibration)
    if verdict is not None and verdict.get("level") != "good":
        # Written with --allow-poor, or with caveats: said again where it leaves imucal.
        lines.insert(0, f"verdict         {verdict.get('level')}: {verdict.get('reason')}")
    lines += [f"  - {n}" for n in result.notes]
    lines += [f"wrote {p}" for p, _ in result.files]
    print("\n".join(lines))


def _verdict_of(calibration: Path) -> dict | None:
    """The run's verdict in a calibration file (None for a file without one: version 1, or
    written from Python without a run)."""
    import json

    try:
        verdict = json.loads(calibration.read_text(encoding="utf-8")).get("verdict")
    except (OSError, ValueError, AttributeError):
        return None
    return verdict if isinstance(verdict, dict) else None


@app.command("noise")
@shared_options(NOISE_INPUT_OPTIONS)
def noise_cmd(
    recording: Annotated[Path, typer.Argument(
        metavar="FILE", show_default=False,
        help="A long still recording (the same formats as a session); text and Parquet are "
             "read a chunk at a time, in bounded memory.")],
    calibration: Annotated[Path | None, typer.Option(
        "--calibration", "-c", metavar="CALIB.json", show_default=False,
        help="Apply this calibration first: figures in calibrated units (needed for raw "
             "counts).")] = None,
    out: Annotated[Path | None, typer.Option(
        "--out", "-o", metavar="NOISE.json", show_default=False,
        help="Write the figures and the Allan deviation curves (JSON, with units).")] = None,
    kalibr: Annotated[Path | None, typer.Option(
        "--kalibr", metavar="IMU.yaml", show_default=False,
        help="Write Kalibr's imu.yaml noise block.")] = None,
    rrd: Annotated[Path | None, typer.Option(
        "--rrd", metavar="NOISE.rrd", show_default=False,
        help="Save a Rerun recording with the log-log Allan deviation plot.")] = None,
    chunk_mb: Annotated[int, typer.Option(
        "--chunk-mb", metavar="MB", callback=at_least(1),
        help="Megabytes of the file read at a time.")] = 16,
    options: dict[str, Any] = None,  # INPUT_OPTIONS
    verbose: VerboseOpt = False,
) -> None:
    """Noise figures of a still recording: overlapping Allan deviation, white noise density,
    bias instability, random walk, and Kalibr's imu.yaml noise block."""
    load_kw = load_kwargs(**pick(options, INPUT_OPTIONS))
    check_outputs([out, kalibr, rrd], [recording, load_kw["gyro_path"], calibration])
    save = None
    if rrd is not None:
        with viewer_available():
            from viewer.noise import save_noise_recording as save
    progress = Progress(verbose)
    from imucal.io.noise_file import measure_noise
    from imucal.io.noise_json import kalibr_block, noise_to_dict

    cal = None
    unit_notes = []
    if calibration is not None:
        from imucal.io.calibration_file import recorded_units

        with progress.stage(f"reading {calibration.name}"):
            cal, units = recorded_units(calibration)
        # The calibration states the units its recording was in: a unit not given is that one
        # (a still gyroscope cannot tell rad/s from deg/s by itself).
        for key, unit in units.items():
            if load_kw[key] == "auto":
                load_kw[key] = unit
                sensor = {"acc_unit": "accelerometer", "gyro_unit": "gyroscope"}[key]
                unit_notes.append(f"{sensor} read in {unit}, as {calibration.name} states")
    with progress.stage(f"reading {recording.name} a chunk at a time"):
        report = measure_noise(recording, calibration=cal, chunk_bytes=chunk_mb << 20,
                               **load_kw)
    data = noise_to_dict(report)
    data["notes"] = unit_notes + data["notes"]
    block, knotes = kalibr_block(data)
    if report.still is False:
        # Figures of a recording that moved measure the motion: no noise block from them.
        if kalibr is not None:
            raise ImucalError("the recording is not still (see 'imucal noise' without "
                              "--kalibr): no Kalibr noise block from it; nothing written",
                              source=str(recording), field="--kalibr")
        block, knotes = None, []
    written = _write_outputs(data, block, out, kalibr)
    if rrd is not None and save is not None:
        with progress.stage(f"writing {rrd}"):
            save(data, rrd)
        written.append(str(rrd))
    print(_noise_summary(data, block, knotes, written))


def _write_outputs(data: dict, block: dict | None, out: Path | None, kalibr: Path | None
                   ) -> list[str]:
    import json

    from imucal.io.atomic import write_text_atomic

    written = []
    if out is not None:
        doc = {"format": "imucal-noise", "format_version": 1, "noise": data, "kalibr": block}
        if block is None:
            doc["still"] = False  # export --noise refuses it (exports/common.py)
        write_text_atomic(out, json.dumps(doc, indent=2, allow_nan=False) + "\n")
        written.append(str(out))
    if kalibr is not None and block is not None:
        from imucal.io.exports.kalibr import ROSTOPIC
        from imucal.io.exports.yaml_text import comment_block, dump
        from imucal.io.noise_json import KALIBR_UNITS

        missing = [k for k, v in block.items() if v is None]
        head = comment_block(["Kalibr imu.yaml noise block, written by imucal noise",
                              data["source"], *[f"{k}: {u}" for k, u in KALIBR_UNITS.items()],
                              *[f"{k}: not determined by this recording" for k in missing]])
        doc = {k: v for k, v in block.items() if v is not None and k != "update_rate"}
        doc["rostopic"] = ROSTOPIC
        if block["update_rate"] is not None:
            doc["update_rate"] = block["update_rate"]
        write_text_atomic(kalibr, head + dump(doc))
        written.append(str(kalibr))
    return written


def _value(sn: dict, key: str, i: int) -> str:
    """``1.23e-4 unit (±5 %)``, or ``n/a`` for a figure the data do not determine."""
    v = sn[key][i]
    if v is None:
        return "n/a"
    err = (sn.get(key + "_rel_err") or [None] * 3)[i]
    return f"{v:.4g} {sn[key + '_unit']}" + (f" (±{100 * err:.2g} %)" if err else "")


def _noise_summary(data: dict, block: dict | None, knotes: list[str], written: list[str]
                   ) -> str:
    lines = [f"source          {data['source']}"]
    for key in ("accelerometer", "gyroscope"):
        sn = data.get(key)
        if not sn:
            continue
        n = sn["samples"]
        lines.append(f"{key:<15} {n} samples at {sn['rate_hz']:.6g} Hz "
                     f"({n / sn['rate_hz']:.1f} s), {sn['unit']}")
        for i, axis in enumerate("xyz"):
            lines.append(f"  {axis}  white {_value(sn, 'white_noise_density', i)}   bias "
                         f"instability {_value(sn, 'bias_instability', i)}   random walk "
                         f"{_value(sn, 'random_walk', i)}")
    if block is None:
        lines.append("kalibr imu.yaml  none: the recording is not still, its figures measure "
                     "the motion (see the notes)")
    else:
        lines.append("kalibr imu.yaml")
        lines += [f"  {k}: {fmt(v, '.6g')}" for k, v in block.items()]
    notes = list(data.get("notes", [])) + knotes
    if notes:
        lines.append("notes:")
        lines += [f"  - {n}" for n in notes]
    lines += [f"wrote {w}" for w in written]
    return "\n".join(lines)


@app.command("inspect")
@shared_options(INSPECT_INPUT_OPTIONS)
def inspect_cmd(
    files: Annotated[list[Path], typer.Argument(
        metavar="FILE...", show_default=False,
        help="Recordings or logs: ROS 1/2 bags and MCAP, PX4 ULog, ArduPilot DataFlash and "
             "MAVLink .tlog, .mat, HDF5, CSV/text, Parquet.")],
    as_json: Annotated[bool, typer.Option(
        "--json", help="One JSON document on stdout, for scripts.")] = False,
    options: dict[str, Any] = None,  # INPUT_OPTIONS (how a table is read)
) -> int:
    """List every sensor stream of each file (kind, name, samples, rate, unit, duration, gaps,
    frame) and which ones the other commands take by default. Exit 1 if a file cannot be
    read."""
    import json

    from imucal.io.inspect import as_text, inspect_file

    load_kw = load_kwargs(**pick(options, INPUT_OPTIONS))
    listed = [inspect_file(f, **load_kw) for f in files]
    if as_json:
        print(json.dumps([x.to_dict() for x in listed], indent=1, allow_nan=False,
                         default=lambda v: None))
    else:
        for x in listed:
            for line in as_text(x):
                print(line)
    return 1 if any(x.error for x in listed) else 0
