"""The ``imucal`` command: calibrate, apply, synth, view.

Only the standard library and typer are imported at module level so that ``imucal --help``
stays fast; numpy, scipy, polars and the core modules are imported inside the commands, and
rerun only by ``--rrd`` and ``view``.

Exit codes: 0 success; 1 a problem with the user's input, files or settings (one line on
stderr, ``imucal: error: ...``); 2 a usage error (unknown option, bad option value); 3 an
internal error (a bug in imucal, one line; ``IMUCAL_DEBUG=1`` shows the traceback); 130
interrupted (Ctrl-C).
"""

from __future__ import annotations

import contextlib
import functools
import inspect
import math
import os
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated, Any

import typer

from .errors import ImucalError

EXIT_OK, EXIT_ERROR, EXIT_USAGE, EXIT_INTERNAL, EXIT_INTERRUPTED = 0, 1, 2, 3, 130

SETTINGS = ("window", "min_len", "k", "init", "statistic", "single_segment", "delta",
            "min_blocks", "g", "lam", "points", "gyro_lam", "gyro_bias", "optimise_gyro_bias",
            "gyro_nominal_scale")


def _settings_defaults() -> dict[str, Any]:
    """The defaults of :class:`imucal.settings.Settings` (a module free of numpy, so ``--help``
    stays fast)."""
    import dataclasses

    from .settings import Settings

    return dataclasses.asdict(Settings())


DEFAULTS: dict[str, Any] = _settings_defaults()
ROLES = ("t", "ax", "ay", "az", "gx", "gy", "gz")

app = typer.Typer(
    name="imucal",
    help="Calibrate an IMU's accelerometer and gyroscope from an ordinary recording "
         "(still poses with turns between them).",
    add_completion=False,
    no_args_is_help=True,
    rich_markup_mode=None,
    pretty_exceptions_enable=False,
    context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100},
)


# --- option values ---------------------------------------------------------------------------


def _key(text: str) -> str:
    """'m/s^2' -> 'ms2', 'Deg/s' -> 'degs', '°/s' -> 'degs'."""
    text = text.strip().lower().replace("°", "deg").replace("²", "2")
    return "".join(c for c in text if c.isalnum())


_ACC_UNITS = {"auto": "auto", "g": "g", "ms2": "m/s^2", "mss": "m/s^2", "counts": "counts",
              "count": "counts", "raw": "counts", "lsb": "counts"}
_GYRO_UNITS = {"auto": "auto", "rads": "rad/s", "rad": "rad/s", "degs": "deg/s", "deg": "deg/s",
               "dps": "deg/s", "counts": "counts", "count": "counts", "raw": "counts",
               "lsb": "counts"}
_TIME_UNITS = {"s": "s", "sec": "s", "ms": "ms", "us": "us", "µs": "us", "ns": "ns"}


def _choice(table: dict[str, str], expected: str, allow_auto: bool = True):
    def check(value: str) -> str:
        got = table.get(_key(value))
        if got is None or (got == "auto" and not allow_auto):
            raise typer.BadParameter(f"expected {expected}, got {value!r}")
        return got
    return check


def _one_of(*choices: str):
    def check(value: str) -> str:
        if value not in choices:
            raise typer.BadParameter(f"expected one of {', '.join(choices)}, got {value!r}")
        return value
    return check


def _positive(value: float | None) -> float | None:
    if value is not None and not (math.isfinite(value) and value > 0):
        raise typer.BadParameter(f"must be a positive number, got {value:g}")
    return value


def _non_negative(value: float | None) -> float | None:
    if value is not None and not (math.isfinite(value) and value >= 0):
        raise typer.BadParameter(f"must be a number >= 0, got {value:g}")
    return value


def _at_least(n: int):
    def check(value: int | None) -> int | None:
        if value is not None and value < n:
            raise typer.BadParameter(f"must be at least {n}, got {value}")
        return value
    return check


def _fraction(value: float | None) -> float | None:
    if value is not None and not 0.0 < value < 1.0:
        raise typer.BadParameter(f"must be a fraction between 0 and 1, got {value:g}")
    return value


def _lambda(value: str) -> str:
    if value.strip().lower() == "auto":
        return "auto"
    try:
        lam = float(value)
    except ValueError:
        lam = float("nan")
    if not (math.isfinite(lam) and lam >= 0):
        raise typer.BadParameter(f"expected 'auto' or a number >= 0, got {value!r}")
    return value.strip()


def parse_columns(text: str | None) -> dict[str, str | int] | None:
    """``ax=acc_x,ay=acc_y,...`` -> {"ax": "acc_x", ...}; a number is a 0-based position."""
    if text is None or not text.strip():
        return None
    mapping: dict[str, str | int] = {}
    for item in text.split(","):
        role, sep, col = (s.strip() for s in item.partition("="))
        if not sep or not role or not col:
            raise typer.BadParameter(f"expected ROLE=COLUMN pairs separated by commas, e.g. "
                                     f"'ax=acc_x,ay=acc_y', got {item.strip()!r}")
        role = role.lower()
        if role not in ROLES:
            raise typer.BadParameter(f"unknown role {role!r}; expected one of {', '.join(ROLES)}")
        if role in mapping:
            raise typer.BadParameter(f"role {role!r} given twice")
        mapping[role] = int(col) if col.isdigit() else col
    return mapping


def _columns(value: str | None) -> str | None:
    parse_columns(value)
    return value


# --- shared options ----------------------------------------------------------------------------

_IN = "Input"
_DET = "Static detector (method.md §1)"
_GRP = "Grouping (§2)"
_ACC = "Accelerometer (§3)"
_GYR = "Gyroscope (§4)"

SessionArg = Annotated[Path, typer.Argument(
    metavar="SESSION", show_default=False,
    help="Recording: .mat (v5 or v7.3), CSV/TSV/text or Parquet; the format is read from the "
         "content, not the name.")]
GyroOpt = Annotated[Path | None, typer.Option(
    "--gyro", metavar="FILE", rich_help_panel=_IN,
    help="Separate gyroscope file (SESSION then holds the accelerometer).")]
RateOpt = Annotated[float | None, typer.Option(
    "--rate", metavar="HZ", callback=_positive, rich_help_panel=_IN,
    help="Sample rate for files without a time column.")]
AccUnitOpt = Annotated[str, typer.Option(
    "--acc-unit", metavar="g|m/s^2|counts|auto", rich_help_panel=_IN,
    callback=_choice(_ACC_UNITS, "g, m/s^2, counts or auto"),
    help="Unit of the raw accelerometer.")]
GyroUnitOpt = Annotated[str, typer.Option(
    "--gyro-unit", metavar="rad/s|deg/s|counts|auto", rich_help_panel=_IN,
    callback=_choice(_GYRO_UNITS, "rad/s, deg/s, counts or auto"),
    help="Unit of the raw gyroscope (deg/s is converted to rad/s).")]
ColumnsOpt = Annotated[str | None, typer.Option(
    "--columns", metavar="ax=COL,...", callback=_columns, rich_help_panel=_IN,
    help="Which column is which: roles t, ax, ay, az, gx, gy, gz mapped to column names, or "
         "to 0-based positions for a file without a header.")]
TimeUnitOpt = Annotated[str, typer.Option(
    "--time-unit", metavar="s|ms|us|ns", rich_help_panel=_IN,
    callback=_choice(_TIME_UNITS, "s, ms, us or ns", allow_auto=False),
    help="Unit of the time column.")]
AccOnlyOpt = Annotated[bool, typer.Option(
    "--acc-only", rich_help_panel=_IN,
    help="The file holds an accelerometer and no gyroscope: calibrate the accelerometer alone.")]
VerboseOpt = Annotated[bool, typer.Option(
    "--verbose", "-v", help="Show progress on stderr (shown anyway when stderr is a terminal).")]

WindowOpt = Annotated[int | None, typer.Option(
    "--window", metavar="N", callback=_at_least(3), rich_help_panel=_DET, show_default=False,
    help="Variance window in samples [default: 1.01 s at the session's rate].")]
MinLenOpt = Annotated[int | None, typer.Option(
    "--min-len", metavar="N", callback=_at_least(1), rich_help_panel=_DET, show_default=False,
    help="Shortest static block in samples [default: 1 s at the session's rate].")]
KOpt = Annotated[float, typer.Option(
    "--k", metavar="K", callback=_positive, rich_help_panel=_DET,
    help="Threshold multiplier: still where s2 < k * s2_init.")]
InitOpt = Annotated[tuple[float, float] | None, typer.Option(
    "--init", metavar="START END", rich_help_panel=_DET, show_default=False,
    help="Initial still interval, seconds from the first sample "
         f"[default: {DEFAULTS['init'][0]:g} {DEFAULTS['init'][1]:g}].")]
InitStartOpt = Annotated[float | None, typer.Option(
    "--init-start", metavar="S", rich_help_panel=_DET, show_default=False,
    help=f"Start of the initial still interval [default: {DEFAULTS['init'][0]:g}].")]
InitEndOpt = Annotated[float | None, typer.Option(
    "--init-end", metavar="S", rich_help_panel=_DET, show_default=False,
    help=f"End of the initial still interval [default: {DEFAULTS['init'][1]:g}].")]
StatisticOpt = Annotated[str, typer.Option(
    "--statistic", metavar="thesis|imu_tk", callback=_one_of("thesis", "imu_tk"),
    rich_help_panel=_DET,
    help="thesis: sum of squared variances (M1); imu_tk: norm of the variances.")]
SingleSegmentOpt = Annotated[bool, typer.Option(
    "--single-segment", rich_help_panel=_GRP,
    help="One segment for the whole session (imu_tk's behaviour).")]
DeltaOpt = Annotated[float, typer.Option(
    "--delta", callback=_positive, rich_help_panel=_GRP,
    help="Jump of the calibrated still magnitude, relative to |g|, that starts a new segment.")]
MinBlocksOpt = Annotated[int, typer.Option(
    "--min-blocks", metavar="N", callback=_at_least(1), rich_help_panel=_GRP,
    help="Fewest static blocks a segment may have.")]
GOpt = Annotated[float | None, typer.Option(
    "--g", metavar="VALUE", callback=_positive, rich_help_panel=_ACC, show_default=False,
    help="|g| in the calibrated output's unit, e.g. 9.80665 or a local value "
         "[default: 1 (g), or 9.80665 for m/s^2 input].")]
LambdaOpt = Annotated[str, typer.Option(
    "--lambda", metavar="auto|VALUE", callback=_lambda, rich_help_panel=_ACC,
    help="Tikhonov weight: auto (L-curve corner) or a fixed value >= 0.")]
PointsOpt = Annotated[str, typer.Option(
    "--points", metavar="thesis|chunks|mean", callback=_one_of("thesis", "chunks", "mean"),
    rich_help_panel=_ACC,
    help="Fit points per block: thesis (99 samples averaged in groups of 10), chunks (10 "
         "chunk means) or mean (one per block).")]
GyroLambdaOpt = Annotated[float, typer.Option(
    "--gyro-lambda", metavar="VALUE", callback=_non_negative, rich_help_panel=_GYR,
    help="Tikhonov weight of the gyroscope fit.")]
GyroBiasOpt = Annotated[str, typer.Option(
    "--gyro-bias", metavar="all|first", callback=_one_of("all", "first"), rich_help_panel=_GYR,
    help="Gyroscope bias from every static block (all) or the first (thesis).")]
OptimiseGyroBiasOpt = Annotated[bool, typer.Option(
    "--optimise-gyro-bias", "--optimize-gyro-bias", rich_help_panel=_GYR,
    help="Fit the gyroscope bias too, with the static estimate as its prior.")]
GyroSensitivityOpt = Annotated[float | None, typer.Option(
    "--gyro-sensitivity", metavar="RAD/S", callback=_positive, rich_help_panel=_GYR,
    show_default=False,
    help="Nominal gyroscope sensitivity in rad/s per count (datasheet), for a gyroscope in "
         "raw counts [default: found from the data].")]


# The options several commands share, in --help order: (parameter, option, default).
INPUT_OPTIONS = (
    ("gyro", GyroOpt, None), ("rate", RateOpt, None), ("acc_unit", AccUnitOpt, "auto"),
    ("gyro_unit", GyroUnitOpt, "auto"), ("columns", ColumnsOpt, None),
    ("time_unit", TimeUnitOpt, "s"), ("acc_only", AccOnlyOpt, False))
SETTING_OPTIONS = (
    ("window", WindowOpt, DEFAULTS["window"]), ("min_len", MinLenOpt, DEFAULTS["min_len"]),
    ("k", KOpt, DEFAULTS["k"]), ("init", InitOpt, None), ("init_start", InitStartOpt, None),
    ("init_end", InitEndOpt, None), ("statistic", StatisticOpt, DEFAULTS["statistic"]),
    ("single_segment", SingleSegmentOpt, DEFAULTS["single_segment"]),
    ("delta", DeltaOpt, DEFAULTS["delta"]), ("min_blocks", MinBlocksOpt, DEFAULTS["min_blocks"]),
    ("g", GOpt, DEFAULTS["g"]), ("lam", LambdaOpt, DEFAULTS["lam"]),
    ("points", PointsOpt, DEFAULTS["points"]),
    ("gyro_lambda", GyroLambdaOpt, DEFAULTS["gyro_lam"]),
    ("gyro_bias", GyroBiasOpt, DEFAULTS["gyro_bias"]),
    ("optimise_gyro_bias", OptimiseGyroBiasOpt, DEFAULTS["optimise_gyro_bias"]),
    ("gyro_sensitivity", GyroSensitivityOpt, DEFAULTS["gyro_nominal_scale"]))


def shared_options(*groups: tuple):
    """Give a command the options of ``groups`` where its ``options`` parameter stands, and
    hand them to it as that one mapping.

    typer reads a command's options from its signature, so without this every command that
    loads and calibrates a recording would spell out the same two dozen parameters.
    """
    specs = [spec for group in groups for spec in group]

    def decorate(fn):
        own = inspect.signature(fn, eval_str=True)
        params = []
        for p in own.parameters.values():
            if p.name == "options":
                params += [inspect.Parameter(name, inspect.Parameter.POSITIONAL_OR_KEYWORD,
                                             default=default, annotation=option)
                           for name, option, default in specs]
            else:
                params.append(p)

        @functools.wraps(fn)
        def command(**kwargs):
            options = {name: kwargs.pop(name) for name, _, _ in specs}
            return fn(options=options, **kwargs)

        command.__signature__ = own.replace(parameters=params)
        return command

    return decorate


def _pick(options: dict[str, Any], group: tuple) -> dict[str, Any]:
    return {name: options[name] for name, _, _ in group}


def _settings(*, window, min_len, k, init, init_start, init_end, statistic, single_segment,
              delta, min_blocks, g, lam, points, gyro_lambda, gyro_bias, optimise_gyro_bias,
              gyro_sensitivity) -> dict[str, Any]:
    """The options as keyword arguments of imucal.calibrate (every key of Settings)."""
    if init is not None and (init_start is not None or init_end is not None):
        raise _usage("give the initial interval either as --init START END or as "
                     "--init-start/--init-end, not both", "'--init'")
    start, end = init if init is not None else DEFAULTS["init"]
    start = start if init_start is None else init_start
    end = end if init_end is None else init_end
    if not (math.isfinite(start) and math.isfinite(end) and 0 <= start < end):
        raise _usage(f"the initial still interval must satisfy 0 <= START < END, got "
                     f"{start:g} {end:g}", "'--init'")
    return {"window": window, "min_len": min_len, "k": k, "init": (start, end),
            "statistic": statistic, "single_segment": single_segment, "delta": delta,
            "min_blocks": min_blocks, "g": g, "lam": lam if lam == "auto" else float(lam),
            "points": points, "gyro_lam": gyro_lambda, "gyro_bias": gyro_bias,
            "optimise_gyro_bias": optimise_gyro_bias, "gyro_nominal_scale": gyro_sensitivity}


def _load_kwargs(*, gyro, rate, acc_unit, gyro_unit, columns, time_unit, acc_only=False
                 ) -> dict[str, Any]:
    return {"gyro_path": gyro, "rate": rate, "acc_unit": acc_unit, "gyro_unit": gyro_unit,
            "columns": parse_columns(columns), "time_unit": time_unit, "acc_only": acc_only}


def _usage(message: str, hint: str) -> typer.BadParameter:
    """A usage error (exit 2) found after parsing, shown like click's own."""
    ctx = typer.main.get_current_context(silent=True)
    return typer.BadParameter(message, ctx=ctx, param_hint=hint)


# --- progress and output helpers ---------------------------------------------------------------


class Progress:
    """Stage lines on stderr ("loading x.mat... 0.3 s") when stderr is a terminal or -v."""

    def __init__(self, verbose: bool):
        self.enabled = verbose or _isatty(sys.stderr)

    @contextlib.contextmanager
    def stage(self, label: str) -> Iterator[None]:
        if not self.enabled:
            yield
            return
        sys.stderr.write(f"{label}... ")
        sys.stderr.flush()
        t0 = time.perf_counter()
        try:
            yield
        except BaseException:
            sys.stderr.write("failed\n")
            sys.stderr.flush()
            raise
        sys.stderr.write(f"{time.perf_counter() - t0:.1f} s\n")
        sys.stderr.flush()


def _isatty(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


def _check_outputs(outputs: list[Path | None], inputs: list[Path | None]) -> list[Path]:
    """Refuse bad output paths before any work: missing directory, an input, or a duplicate."""
    from .atomic import check_output_path

    ins = tuple(str(p) for p in inputs if p is not None)
    seen: dict[Path, Path] = {}
    checked = []
    for out in outputs:
        if out is None:
            continue
        if out.is_dir():
            raise ImucalError("is a directory; expected a file name", source=str(out),
                              field="output path")
        check_output_path(out, ins)
        key = out.resolve()
        if key in seen:
            raise ImucalError(f"the same file is given for two outputs ({seen[key]} and {out})",
                              source=str(out), field="output path")
        seen[key] = out
        checked.append(out)
    return checked


def _gyro_sidecar(path: Path) -> Path:
    """Where write_calibrated puts the gyroscope when it does not share the accelerometer's
    timestamps (CSV/Parquet only)."""
    return path.with_name(path.stem + ".gyro" + path.suffix)


def _fmt(x: float | None, spec: str = ".3g") -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "n/a"
    return format(x, spec)


def _vec(values, spec: str = ".6g") -> str:
    return " ".join(format(float(v), spec) for v in values)


def _rate(hz: float | None) -> str:
    return "n/a" if hz is None else f"{hz:.4g} Hz"


# --- commands ----------------------------------------------------------------------------------


@app.command()
@shared_options(INPUT_OPTIONS, SETTING_OPTIONS)
def calibrate(
    session: SessionArg,
    out: Annotated[Path, typer.Option("--out", "-o", metavar="CALIB.json", show_default=False,
                                      help="Calibration file to write (JSON).")],
    rrd: Annotated[Path | None, typer.Option(
        "--rrd", metavar="RUN.rrd", help="Also save a Rerun recording of every step.")] = None,
    calibrated: Annotated[Path | None, typer.Option(
        "--calibrated", metavar="OUT.parquet|.csv|.mat",
        help="Also write the calibrated signals.")] = None,
    options: dict[str, Any] = None,  # INPUT_OPTIONS and SETTING_OPTIONS
    verbose: VerboseOpt = False,
) -> None:
    """Calibrate a recording and write the calibration file (and optionally more)."""
    settings = _settings(**_pick(options, SETTING_OPTIONS))
    load_kw = _load_kwargs(**_pick(options, INPUT_OPTIONS))
    gyro = options["gyro"]
    inputs = [session, gyro]
    if calibrated is not None:
        from .export import output_format

        output_format(calibrated)
    outputs = [out, rrd, calibrated]
    if calibrated is not None and calibrated.suffix.lower() != ".mat":
        outputs.append(_gyro_sidecar(calibrated))
    _check_outputs(outputs, inputs)
    save_recording = None
    if rrd is not None:
        save_recording = _import_viewer("viewer.recording", "save_recording")

    progress = Progress(verbose)
    import imucal

    with progress.stage(f"loading {session.name}"):
        sess = imucal.load_session(session, **load_kw)
    with progress.stage(f"calibrating {len(sess.acc)} samples (detect, group, fit)"):
        result = imucal.calibrate(sess, **settings)
    written = []
    with progress.stage(f"writing {out}"):
        imucal.save_calibration(result, out)
    written.append(str(out))
    if calibrated is not None:
        from .export import write_calibrated

        with progress.stage(f"writing {calibrated}"):
            write_calibrated(calibrated, result.calibrated)
        written += _written_tables(calibrated, result.calibrated)
    if rrd is not None and save_recording is not None:
        with progress.stage(f"writing {rrd}"):
            save_recording(result, rrd)
        written.append(str(rrd))
    _print_summary(result, written)


def _written_tables(path: Path, cal) -> list[str]:
    side = _gyro_sidecar(path)
    if path.suffix.lower() != ".mat" and cal.gyro is not None and side.exists():
        import numpy as np

        if not np.array_equal(cal.t_acc, cal.t_gyro):
            return [str(path), str(side)]
    return [str(path)]


def _import_viewer(module: str, name: str):
    import importlib

    try:
        return getattr(importlib.import_module(module), name)
    except ModuleNotFoundError as e:
        if e.name and e.name.split(".")[0] == "rerun":
            why = "rerun-sdk is not installed (pip install 'rerun-sdk==0.41.0')"
        else:
            why = f"module {e.name!r} not found"
        raise ImucalError(f"the viewer is not available: {why}", source=module) from None
    except AttributeError:
        raise ImucalError(f"{module} has no {name}", source="viewer") from None


def _print_summary(result, written: list[str]) -> None:
    from .models import acc_theta, gyro_theta

    s = result.session
    q = result.quality
    cal = result.calibration
    acc_raw = s.acc_unit
    gyro_raw = s.gyro_unit if s.has_gyro else None
    lines = []
    gyro_txt = (f"gyroscope {len(s.gyro)} samples at {_rate(s.gyro_rate)} ({gyro_raw})"
                if s.has_gyro else "no gyroscope")
    lines.append(f"session         {s.source}: {s.duration:.1f} s, accelerometer {len(s.acc)} "
                 f"samples at {_rate(s.acc_rate)} ({acc_raw}), {gyro_txt}")
    det = result.detection
    lines.append(f"static blocks   {len(det.blocks)} (window {det.window}, min length "
                 f"{det.min_len} samples)")
    lines.append(f"segments        {len(result.segments)} ({result.grouping.mode})")
    how = "L-curve corner" if result.settings.lam == "auto" else "fixed"
    lines.append(f"lambda          {_fmt(result.whole.lam, '.3g')} ({how})")
    lines.append(f"{'':28s}{'before':>10s}{'after':>10s}")
    lines.append(f"{'static norm error (mg)':28s}{_fmt(q.static_norm_rms_mg[0]):>10s}"
                 f"{_fmt(q.static_norm_rms_mg[1]):>10s}")
    lines.append(f"{'sample norm error (mg)':28s}{_fmt(q.sample_norm_rms_mg[0]):>10s}"
                 f"{_fmt(q.sample_norm_rms_mg[1]):>10s}  (single samples: sensor noise)")
    if q.gravity_angle_rms_deg is not None:
        ga = q.gravity_angle_rms_deg
        lines.append(f"{'gravity angle (deg)':28s}{_fmt(ga[0]):>10s}{_fmt(ga[1]):>10s}")
    for seg in result.segments:
        lines.append(f"segment {seg.index}       {seg.t_start:.1f}-{seg.t_end:.1f} s, "
                     f"{seg.blocks[1] - seg.blocks[0]} blocks, {seg.orientations} orientations, "
                     f"lambda {_fmt(seg.acc.lam)}, start {seg.acc.report.start_name}")
        th = acc_theta(seg.acc.model)
        lines.append(f"  acc   scale {_vec(th[3:6])}  misalign(yz zy zx) {_vec(th[0:3], '.3g')}"
                     f"  bias {_vec(th[6:9])} {acc_raw}")
        if seg.gyro is not None:
            gt = gyro_theta(seg.gyro.model)
            lines.append(f"  gyro  scale {_vec(gt[6:9])}  misalign {_vec(gt[0:6], '.3g')}"
                         f"  bias {_vec(seg.gyro.model.b)} {gyro_raw} ({seg.gyro.bias_source})")
    lines.append(f"output          calibrated accelerometer in {cal.acc_unit} (|g| = "
                 f"{cal.g:g})" + (", gyroscope in rad/s" if s.has_gyro else ""))
    notes = list(result.warnings) + list(q.notes)
    if notes:
        lines.append("warnings:")
        lines += [f"  - {w}" for w in notes]
    lines += [f"wrote {w}" for w in written]
    print("\n".join(lines))


@app.command()
@shared_options(INPUT_OPTIONS)
def apply(
    calibration: Annotated[Path, typer.Argument(metavar="CALIB.json", show_default=False,
                                                help="Calibration file from 'imucal calibrate'.")],
    session: SessionArg,
    out: Annotated[Path, typer.Option(
        "--out", "-o", metavar="OUT.parquet|.csv|.mat", show_default=False,
        help="Calibrated signals to write; the format follows the name.")],
    options: dict[str, Any] = None,  # INPUT_OPTIONS
    verbose: VerboseOpt = False,
) -> None:
    """Apply a calibration file to a recording and write the calibrated signals.

    The recording's units must be those the calibration was fitted on (a mismatch is refused).
    """
    from .export import output_format

    output_format(out)
    outputs = [out] + ([_gyro_sidecar(out)] if out.suffix.lower() != ".mat" else [])
    _check_outputs(outputs, [calibration, session, options["gyro"]])
    progress = Progress(verbose)
    import imucal

    from .export import write_calibrated

    with progress.stage(f"reading {calibration.name}"):
        cal = imucal.load_calibration(calibration)
    load_kw = _load_kwargs(**_pick(options, INPUT_OPTIONS))
    with progress.stage(f"loading {session.name}"):
        sess = imucal.load_session(session, **load_kw)
    with progress.stage("applying"):
        signals = cal.apply(sess)
    with progress.stage(f"writing {out}"):
        write_calibrated(out, signals)
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
    lines += [f"wrote {w}" for w in _written_tables(out, signals)]
    print("\n".join(lines))


@app.command()
def synth(
    out: Annotated[Path, typer.Argument(metavar="OUT.mat", show_default=False,
                                        help="Session file to write (MATLAB v5).")],
    truth: Annotated[Path | None, typer.Option(
        "--truth", metavar="PATH", show_default=False,
        help="Where to write the true parameters [default: OUT.truth.json].")] = None,
    poses: Annotated[int | None, typer.Option(
        "--poses", metavar="N", callback=_at_least(2), show_default=False,
        help="Number of still poses [default: 30].")] = None,
    minutes: Annotated[float | None, typer.Option(
        "--minutes", metavar="M", callback=_positive, show_default=False,
        help="Session length; sets the number of poses from the durations.")] = None,
    seed: Annotated[int, typer.Option("--seed", help="Random seed.")] = 0,
    still: Annotated[float, typer.Option(
        "--still", metavar="S", callback=_positive, help="Seconds still in each pose.")] = 3.0,
    move: Annotated[float, typer.Option(
        "--move", metavar="S", callback=_positive, help="Seconds of each turn.")] = 2.0,
    init_still: Annotated[float, typer.Option(
        "--init-still", metavar="S", callback=_positive,
        help="Seconds still at the start.")] = 5.0,
    acc_rate: Annotated[float, typer.Option(
        "--acc-rate", metavar="HZ", callback=_positive, help="Accelerometer rate.")] = 100.0,
    gyro_rate: Annotated[float | None, typer.Option(
        "--gyro-rate", metavar="HZ", callback=_positive, show_default=False,
        help="Gyroscope rate [default: the accelerometer's].")] = None,
    acc_noise: Annotated[float, typer.Option(
        "--acc-noise", metavar="G", callback=_non_negative,
        help="Accelerometer white noise per axis, g.")] = 0.003,
    gyro_noise: Annotated[float, typer.Option(
        "--gyro-noise", metavar="RAD/S", callback=_non_negative,
        help="Gyroscope white noise per axis, rad/s.")] = 0.003,
    drift: Annotated[float, typer.Option(
        "--drift", metavar="RAD/S", callback=_non_negative,
        help="Total change of the gyroscope bias over the session.")] = 0.0,
    change_at: Annotated[float | None, typer.Option(
        "--change-at", metavar="FRACTION", callback=_fraction, show_default=False,
        help="Switch to new sensor parameters after this fraction of the poses.")] = None,
    acc_unit: Annotated[str, typer.Option(
        "--acc-unit", metavar="g|m/s^2|counts",
        callback=_choice(_ACC_UNITS, "g, m/s^2 or counts", allow_auto=False),
        help="Unit of the written accelerometer.")] = "g",
    gyro_unit: Annotated[str, typer.Option(
        "--gyro-unit", metavar="rad/s|deg/s|counts",
        callback=_choice(_GYRO_UNITS, "rad/s, deg/s or counts", allow_auto=False),
        help="Unit of the written gyroscope.")] = "rad/s",
    verbose: VerboseOpt = False,
) -> None:
    """Write a synthetic session with known parameters, and its truth as JSON."""
    if poses is not None and minutes is not None:
        raise _usage("give either --poses or --minutes, not both", "'--minutes'")
    if minutes is not None:
        # duration ~ init_still + n * still + (n - 1) * move (the durations vary by +-20 %)
        poses = max(2, round((minutes * 60.0 - init_still + move) / (still + move)))
    poses = 30 if poses is None else poses
    truth = truth if truth is not None else out.with_suffix(".truth.json")
    _check_outputs([out, truth], [])
    progress = Progress(verbose)
    from .export import write_session_mat, write_truth
    from .synth import make_session

    with progress.stage(f"generating {poses} poses"):
        sess, tr = make_session(poses=poses, seed=seed, still=still, move=move,
                                init_still=init_still, acc_rate=acc_rate, gyro_rate=gyro_rate,
                                acc_noise=acc_noise, gyro_noise=gyro_noise, gyro_drift=drift,
                                change_at=change_at, acc_unit=acc_unit, gyro_unit=gyro_unit)
    with progress.stage(f"writing {out}"):
        write_session_mat(out, sess, gyro_unit=gyro_unit)
        write_truth(truth, tr)
    change = "" if tr.t_change is None else f", parameters change at {tr.t_change:.1f} s"
    print(f"session         {poses} poses, {sess.duration:.1f} s, accelerometer "
          f"{len(sess.acc)} samples at {_rate(sess.acc_rate)} ({acc_unit}), gyroscope "
          f"{len(sess.gyro)} samples at {_rate(sess.gyro_rate)} ({gyro_unit}){change}\n"
          f"wrote {out}\nwrote {truth}")


@app.command()
@shared_options(INPUT_OPTIONS, SETTING_OPTIONS)
def view(
    target: Annotated[Path, typer.Argument(
        metavar="SESSION|RUN.rrd", show_default=False,
        help="A recording to calibrate and show, or a saved .rrd to open.")],
    save: Annotated[Path | None, typer.Option(
        "--save", metavar="FILE.rrd", help="Save the recording instead of opening a viewer.")
    ] = None,
    web: Annotated[bool, typer.Option("--web", help="Serve the web viewer.")] = False,
    port: Annotated[int, typer.Option("--port", metavar="N", min=1, max=65535,
                                      help="Port of the web viewer.")] = 9090,
    options: dict[str, Any] = None,  # INPUT_OPTIONS and SETTING_OPTIONS
) -> int:
    """Calibrate a recording and show every step in Rerun (or open a saved .rrd).

    Without a display (and without --web) the recording is written to SESSION-STEM.rrd in the
    current directory instead.
    """
    settings = _settings(**_pick(options, SETTING_OPTIONS))
    load_kw = _load_kwargs(**_pick(options, INPUT_OPTIONS))
    gyro = options["gyro"]
    load_defaults = _load_kwargs(**{name: default for name, _, default in INPUT_OPTIONS})
    load_options = {key: v for key, v in load_kw.items() if v != load_defaults[key]}
    overrides = {key: v for key, v in settings.items() if v != DEFAULTS[key]}
    if not target.exists():
        raise ImucalError("file not found", source=str(target))
    if save is not None:
        _check_outputs([save], [target, gyro])
    view_fn = _import_viewer("viewer.app", "show")
    rc = view_fn(str(target), save=None if save is None else str(save), web=web, port=port,
                 load_options=load_options or None, **overrides)
    return int(rc or 0)


def _version(value: bool) -> None:
    if value:
        from importlib.metadata import PackageNotFoundError, version

        try:
            v = version("imucal-rerun")
        except PackageNotFoundError:
            v = "unknown"
        print(f"imucal {v}")
        raise typer.Exit()


@app.callback()
def _root(
    version: Annotated[bool, typer.Option("--version", callback=_version, is_eager=True,
                                          help="Show the version and exit.")] = False,
) -> None:
    """Calibrate an IMU's accelerometer and gyroscope from an ordinary recording.

    Exit codes: 0 success, 1 a problem with the input, files or settings, 2 a usage error,
    3 an internal error, 130 interrupted.
    """


# --- entry point -------------------------------------------------------------------------------


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _err(message: str, prog: str = "imucal") -> None:
    try:
        sys.stderr.write(f"{prog}: {_one_line(message)}\n")
        sys.stderr.flush()
    except (OSError, ValueError):
        pass


def _show_warning(message, category, filename, lineno, file=None, line=None,
                  prog: str = "imucal") -> None:
    """Python warnings from the libraries, as one line each."""
    _err(f"warning: {category.__name__}: {message}", prog)


def _on_sigterm(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def main(argv: list[str] | None = None, *, command: str | None = None,
         prog: str = "imucal") -> int:
    """Run the command line; return the exit code (never a traceback for the user).

    ``command`` runs one subcommand directly under the name ``prog`` (``imucal-view`` is
    ``imucal view``)."""
    import warnings

    args = sys.argv[1:] if argv is None else list(argv)
    # The fits work on small matrices: a second BLAS thread only spins (measured in bench/:
    # 1.5 s CPU for 0.8 s wall on a 60-minute session). Set before numpy is first imported;
    # a user's own setting wins.
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    # A polite kill (SIGTERM) unwinds like Ctrl-C, so a write in progress removes its
    # temporary file instead of leaving it beside the output.
    import signal

    with contextlib.suppress(ValueError):  # not the main thread (tests): keep the default
        signal.signal(signal.SIGTERM, _on_sigterm)
    debug = os.environ.get("IMUCAL_DEBUG", "") not in ("", "0")
    if not debug:
        warnings.showwarning = functools.partial(_show_warning, prog=prog)
    err = functools.partial(_err, prog=prog)
    try:
        cli = typer.main.get_command(app)
        if command is not None:
            cli = cli.commands[command]
        rv = cli.main(args, prog_name=prog, standalone_mode=False)
        if rv == EXIT_INTERRUPTED:
            err("interrupted")
        return rv if isinstance(rv, int) else EXIT_OK
    except ImucalError as e:
        err(f"error: {e}")
        return EXIT_ERROR
    except typer.Abort:
        err("aborted")
        return EXIT_ERROR
    except typer.TyperException as e:  # click's usage errors (exit 2) and the like
        show = getattr(e, "show", None)
        if show is not None:
            show()
        else:
            err(f"error: {e}")
        return int(getattr(e, "exit_code", EXIT_USAGE))
    except KeyboardInterrupt:
        err("interrupted")
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        # The reader of stdout went away (e.g. `imucal ... | head`): stop quietly.
        with contextlib.suppress(OSError):
            sys.stdout = open(os.devnull, "w")  # noqa: SIM115
        return EXIT_ERROR
    except MemoryError:
        err("error: not enough memory")
        return EXIT_ERROR
    except OSError as e:
        if debug:
            raise
        where = e.filename if e.filename is not None else ""
        reason = e.strerror or e.__class__.__name__
        err(f"error: {where}: {reason}" if where else f"error: {reason}")
        return EXIT_ERROR
    except Exception as e:
        if debug:
            raise
        err(f"internal error: {e.__class__.__name__}: {e} (a bug in imucal; run with "
             "IMUCAL_DEBUG=1 for the traceback)")
        return EXIT_INTERNAL


if __name__ == "__main__":
    sys.exit(main())
