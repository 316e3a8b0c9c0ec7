"""Every option the commands share, declared once, and how their values are checked and
turned into the keyword arguments of the core (load_session, calibrate)."""

from __future__ import annotations

import functools
import inspect
import math
from pathlib import Path
from typing import Annotated, Any

import typer


def _settings_defaults() -> dict[str, Any]:
    """The defaults of :class:`imucal.settings.Settings`, the one place they are declared (a
    module free of numpy, so ``--help`` stays fast)."""
    import dataclasses

    from imucal.settings import Settings

    return dataclasses.asdict(Settings())


def _thesis_init() -> tuple[float, float]:
    from imucal.settings import THESIS_INIT

    return THESIS_INIT


DEFAULTS: dict[str, Any] = _settings_defaults()
THESIS_INIT = _thesis_init()  # the initial still interval when --init is not given
SETTINGS = tuple(DEFAULTS)  # every setting's name: its flag, and its key in calib.json
ROLES = ("t", "ax", "ay", "az", "gx", "gy", "gz", "a2x", "a2y", "a2z", "a3x", "a3y", "a3z",
         "g2x", "g2y", "g2z", "g3x", "g3y", "g3z", "mx", "my", "mz", "temp")  # io.column_names


# --- option values ---------------------------------------------------------------------------


def _key(text: str) -> str:
    """'m/s^2' -> 'ms2', 'Deg/s' -> 'degs', '°/s' -> 'degs'."""
    text = text.strip().lower().replace("°", "deg").replace("²", "2")
    return "".join(c for c in text if c.isalnum())


ACC_UNITS = {"auto": "auto", "g": "g", "ms2": "m/s^2", "mss": "m/s^2", "counts": "counts",
              "count": "counts", "raw": "counts", "lsb": "counts"}
GYRO_UNITS = {"auto": "auto", "rads": "rad/s", "rad": "rad/s", "degs": "deg/s", "deg": "deg/s",
               "dps": "deg/s", "counts": "counts", "count": "counts", "raw": "counts",
               "lsb": "counts"}
_TIME_UNITS = {"s": "s", "sec": "s", "ms": "ms", "us": "us", "µs": "us", "ns": "ns"}


def choice(table: dict[str, str], expected: str, allow_auto: bool = True):
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


def positive(value: float | None) -> float | None:
    if value is not None and not (math.isfinite(value) and value > 0):
        raise typer.BadParameter(f"must be a positive number, got {value:g}")
    return value


def sample_rate(value: float | None) -> float | None:
    """--rate: positive, and a usage error (exit 2) below what any IMU records, which only
    overflows the timestamps (issue 27); above the highest, the loader says so."""
    if value is None:
        return None  # no --rate: nothing to import (the limit's module imports numpy)
    from imucal.io.time_base import MIN_RATE_HZ

    if positive(value) is not None and value < MIN_RATE_HZ:
        raise typer.BadParameter(f"must be at least {MIN_RATE_HZ:.4g} Hz (one sample a minute), "
                                 f"got {value:g}")
    return value


def ip_address(value: str) -> str:
    """An IPv4 or IPv6 address (what the viewer's ``--bind`` takes)."""
    import ipaddress

    try:
        return str(ipaddress.ip_address(value))
    except ValueError:
        raise typer.BadParameter(f"must be an IP address such as 127.0.0.1 or 0.0.0.0, got "
                                 f"{value!r}") from None


def non_negative(value: float | None) -> float | None:
    if value is not None and not (math.isfinite(value) and value >= 0):
        raise typer.BadParameter(f"must be a number >= 0, got {value:g}")
    return value


def at_least(n: int):
    def check(value: int | None) -> int | None:
        if value is not None and value < n:
            raise typer.BadParameter(f"must be at least {n}, got {value}")
        return value
    return check


def fraction(value: float | None) -> float | None:
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


def _lambdas(text: str | None) -> tuple[float, ...] | None:
    """``1e-6,1e-4,1e-2`` -> (1e-06, 0.0001, 0.01): at least three values > 0, increasing."""
    if text is None:
        return None
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if (len(values) < 3 or not all(math.isfinite(v) and v > 0 for v in values)
            or any(b <= a for a, b in zip(values, values[1:]))):
        raise typer.BadParameter(f"expected at least three increasing numbers > 0 separated by "
                                 f"commas, got {text!r}")
    return values


def _lambdas_option(value: str | None) -> str | None:
    _lambdas(value)
    return value


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


def parse_triple(text: str | None, option: str) -> tuple[float, float, float]:
    """``X,Y,Z`` -> three numbers (each below 1e6 in size); no value is (0, 0, 0)."""
    if text is None:
        return (0.0, 0.0, 0.0)
    try:
        x = tuple(float(v) for v in text.split(","))
    except ValueError:
        x = ()
    if len(x) != 3 or not all(abs(v) < 1e6 for v in x):
        raise usage_error(f"expected three numbers X,Y,Z, got {text!r}", f"'{option}'")
    return x  # type: ignore[return-value]


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
GyroOpt = Annotated[str | None, typer.Option(
    "--gyro", metavar="FILE|STREAM", rich_help_panel=_IN, show_default=False,
    help="A separate gyroscope file (SESSION then holds the accelerometer), or the gyroscope "
         "stream of a log: a topic (/imu/data_raw), sensor_gyro:1, IMU2 [default: the chosen "
         "accelerometer's IMU].")]
AccOpt = Annotated[str | None, typer.Option(
    "--acc", metavar="STREAM", rich_help_panel=_IN, show_default=False,
    help="The accelerometer stream of a log: a ROS topic (/imu/data_raw), a ULog "
         "sensor_accel:1, a DataFlash IMU2, or its position (0, 1, ...) [default: the first; "
         "imucal inspect lists them].")]
MagOpt = Annotated[str | None, typer.Option(
    "--mag", metavar="STREAM", rich_help_panel=_IN, show_default=False,
    help="The magnetometer stream of a log (checked to exist; recorded beside the "
         "calibration).")]
TempOpt = Annotated[str | None, typer.Option(
    "--temp", metavar="STREAM", rich_help_panel=_IN, show_default=False,
    help="The temperature stream of a log (checked to exist; recorded beside the "
         "calibration).")]
RateOpt = Annotated[float | None, typer.Option(
    "--rate", metavar="HZ", callback=sample_rate, rich_help_panel=_IN,
    help="Sample rate for files without a time column.")]
AccUnitOpt = Annotated[str, typer.Option(
    "--acc-unit", metavar="g|m/s^2|counts|auto", rich_help_panel=_IN,
    callback=choice(ACC_UNITS, "g, m/s^2, counts or auto"),
    help="Unit of the raw accelerometer.")]
GyroUnitOpt = Annotated[str, typer.Option(
    "--gyro-unit", metavar="rad/s|deg/s|counts|auto", rich_help_panel=_IN,
    callback=choice(GYRO_UNITS, "rad/s, deg/s, counts or auto"),
    help="Unit of the raw gyroscope (deg/s is converted to rad/s).")]
ColumnsOpt = Annotated[str | None, typer.Option(
    "--columns", metavar="ax=COL,...", callback=_columns, rich_help_panel=_IN,
    help="Which column is which: roles t, ax, ay, az, gx, gy, gz mapped to column names, or "
         "to 0-based positions for a file without a header.")]
TimeUnitOpt = Annotated[str, typer.Option(
    "--time-unit", metavar="s|ms|us|ns", rich_help_panel=_IN,
    callback=choice(_TIME_UNITS, "s, ms, us or ns", allow_auto=False),
    help="Unit of the time column.")]
AccOnlyOpt = Annotated[bool, typer.Option(
    "--acc-only", rich_help_panel=_IN,
    help="The file holds an accelerometer and no gyroscope: calibrate the accelerometer alone.")]
SpillDirOpt = Annotated[Path | None, typer.Option(
    "--spill-dir", metavar="DIR", rich_help_panel=_IN, show_default=False, exists=True,
    file_okay=False, dir_okay=True, writable=True,
    help="Folder for the temporary file a long recording's signals are mapped from (64 MB and "
         "up), so that the process holds about 0.5 GiB of them at most; on a disk, not a tmpfs "
         "[default: the system's temporary folder, TMPDIR].")]
VerboseOpt = Annotated[bool, typer.Option(
    "--verbose", "-v", help="Show progress on stderr (shown anyway when stderr is a terminal).")]

WindowOpt = Annotated[int | None, typer.Option(
    "--window", metavar="N", callback=at_least(3), rich_help_panel=_DET, show_default=False,
    help="Variance window in samples [default: chosen from the recording: 1.01 s at its rate, "
         "shorter for short holds].")]
MinLenOpt = Annotated[int | None, typer.Option(
    "--min-len", metavar="N", callback=at_least(1), rich_help_panel=_DET, show_default=False,
    help="Shortest static block in samples [default: chosen with the window, 1 s for "
         "1.01 s].")]
KOpt = Annotated[float | None, typer.Option(
    "--k", metavar="K", callback=positive, rich_help_panel=_DET, show_default=False,
    help="Threshold multiplier: still where s2 < k * s2_init [default: chosen from the "
         "recording by a cross-validated error].")]
InitOpt = Annotated[tuple[float, float] | None, typer.Option(
    "--init", metavar="START END", rich_help_panel=_DET, show_default=False,
    help="Initial still interval, seconds from the first sample [default: "
         f"{THESIS_INIT[0]:g} {THESIS_INIT[1]:g} when still there, else the quietest stretches].")]
InitStartOpt = Annotated[float | None, typer.Option(
    "--init-start", metavar="S", rich_help_panel=_DET, show_default=False,
    help=f"Start of the initial still interval [default: {THESIS_INIT[0]:g}].")]
InitEndOpt = Annotated[float | None, typer.Option(
    "--init-end", metavar="S", rich_help_panel=_DET, show_default=False,
    help=f"End of the initial still interval [default: {THESIS_INIT[1]:g}].")]
StatisticOpt = Annotated[str, typer.Option(
    "--statistic", metavar="thesis|imu_tk", callback=_one_of("thesis", "imu_tk"),
    rich_help_panel=_DET,
    help="thesis: sum of squared variances (M1); imu_tk: norm of the variances.")]
SingleSegmentOpt = Annotated[bool, typer.Option(
    "--single-segment", rich_help_panel=_GRP,
    help="One segment for the whole session (imu_tk's behaviour).")]
SplitAlphaOpt = Annotated[float, typer.Option(
    "--split-alpha", metavar="P", callback=fraction, rich_help_panel=_GRP,
    help="Significance level of the test that splits the session where its error conditions "
         "change (F-test of one accelerometer fit against two on the block means, Bonferroni "
         "over the boundaries tried).")]
DeltaOpt = Annotated[float | None, typer.Option(
    "--delta", metavar="VALUE", callback=positive, rich_help_panel=_GRP, show_default=False,
    help="Decide splits by a fixed threshold instead of the test: the change of the calibrated "
         "still magnitude, relative to |g|, that starts a new segment (thesis: 0.01) "
         "[default: decided by the test].")]
MinBlocksOpt = Annotated[int, typer.Option(
    "--min-blocks", metavar="N", callback=at_least(1), rich_help_panel=_GRP,
    help="Fewest static blocks a segment may have.")]
GOpt = Annotated[float | None, typer.Option(
    "--g", metavar="VALUE", callback=positive, rich_help_panel=_ACC, show_default=False,
    help="|g| in the calibrated output's unit, e.g. 9.80665 or a local value "
         "[default: 1 (g), or 9.80665 for m/s^2 input].")]
LambdaOpt = Annotated[str, typer.Option(
    "--lambda", metavar="auto|VALUE", callback=_lambda, rich_help_panel=_ACC,
    help="Tikhonov weight: auto (L-curve corner) or a fixed value >= 0.")]
PointsOpt = Annotated[str, typer.Option(
    "--points", metavar="ml|mean|chunks|thesis",
    callback=_one_of("ml", "mean", "chunks", "thesis"), rich_help_panel=_ACC,
    help="Fit points per block: ml (maximum likelihood: one per block, its mean, weighted by "
         "the square root of its length, evened out where the blocks scatter more than white "
         "noise, the noise bias of the norm removed), mean (the plain block mean), chunks "
         "(--n-group chunk means) or thesis (--n-select samples averaged in groups of "
         "--n-group).")]
LambdasOpt = Annotated[str | None, typer.Option(
    "--lambdas", metavar="L1,L2,...", callback=_lambdas_option, rich_help_panel=_ACC,
    show_default=False,
    help="The L-curve's lambda grid [default: 34 values, 1e-8 to 1e3, three a decade].")]
NSelectOpt = Annotated[int, typer.Option(
    "--n-select", metavar="N", callback=at_least(1), rich_help_panel=_ACC,
    help="Thesis points: samples spread over each block.")]
NGroupOpt = Annotated[int, typer.Option(
    "--n-group", metavar="N", callback=at_least(1), rich_help_panel=_ACC,
    help="Thesis points: samples averaged per point (also the chunks per block).")]
GyroLambdaOpt = Annotated[float, typer.Option(
    "--gyro-lambda", metavar="VALUE", callback=non_negative, rich_help_panel=_GYR,
    help="Tikhonov weight of the gyroscope fit.")]
GyroBiasOpt = Annotated[str, typer.Option(
    "--gyro-bias", metavar="all|first", callback=_one_of("all", "first"), rich_help_panel=_GYR,
    help="Gyroscope bias from every static block (all) or the first (thesis).")]
OptimiseGyroBiasOpt = Annotated[bool | None, typer.Option(
    "--optimise-gyro-bias/--no-optimise-gyro-bias", "--optimize-gyro-bias/--no-optimize-gyro-bias",
    rich_help_panel=_GYR, show_default=False,
    help="Fit the gyroscope bias too, with the static estimate as its prior, or not "
         "[default: whichever predicts held-out turns better (cross-validation)].")]
GyroSensitivityOpt = Annotated[float | None, typer.Option(
    "--gyro-sensitivity", metavar="RAD/S", callback=positive, rich_help_panel=_GYR,
    show_default=False,
    help="Nominal gyroscope sensitivity in rad/s per count (datasheet), for a gyroscope in "
         "raw counts [default: found from the data].")]


# The options several commands share, in --help order: (parameter, option, default).
INPUT_OPTIONS = (
    ("acc", AccOpt, None), ("gyro", GyroOpt, None), ("mag", MagOpt, None),
    ("temp", TempOpt, None), ("rate", RateOpt, None), ("acc_unit", AccUnitOpt, "auto"),
    ("gyro_unit", GyroUnitOpt, "auto"), ("columns", ColumnsOpt, None),
    ("time_unit", TimeUnitOpt, "s"), ("acc_only", AccOnlyOpt, False),
    ("spill_dir", SpillDirOpt, None))


def input_options(acc_only: str) -> tuple:
    """:data:`INPUT_OPTIONS` with ``--acc-only``'s help saying what this command does with the
    accelerometer alone (the flag means the same to the loader everywhere)."""
    opt = Annotated[bool, typer.Option("--acc-only", rich_help_panel=_IN, help=acc_only)]
    return tuple((name, opt if name == "acc_only" else o, d) for name, o, d in INPUT_OPTIONS)


_ACC_ONLY = "The file holds an accelerometer and no gyroscope (or leave its gyroscope out): "
APPLY_INPUT_OPTIONS = input_options(
    _ACC_ONLY + "apply the calibration's accelerometer model alone.")
NOISE_INPUT_OPTIONS = input_options(_ACC_ONLY + "measure the accelerometer's noise alone.")
INSPECT_INPUT_OPTIONS = input_options(
    _ACC_ONLY + "list what the other commands take with --acc-only.")

SETTING_OPTIONS = (
    ("window", WindowOpt, DEFAULTS["window"]), ("min_len", MinLenOpt, DEFAULTS["min_len"]),
    ("k", KOpt, DEFAULTS["k"]), ("init", InitOpt, None), ("init_start", InitStartOpt, None),
    ("init_end", InitEndOpt, None), ("statistic", StatisticOpt, DEFAULTS["statistic"]),
    ("single_segment", SingleSegmentOpt, DEFAULTS["single_segment"]),
    ("split_alpha", SplitAlphaOpt, DEFAULTS["split_alpha"]), ("delta", DeltaOpt, DEFAULTS["delta"]),
    ("min_blocks", MinBlocksOpt, DEFAULTS["min_blocks"]),
    ("g", GOpt, DEFAULTS["g"]), ("lam", LambdaOpt, DEFAULTS["lam"]),
    ("lambdas", LambdasOpt, None), ("points", PointsOpt, DEFAULTS["points"]),
    ("n_select", NSelectOpt, DEFAULTS["n_select"]), ("n_group", NGroupOpt, DEFAULTS["n_group"]),
    ("gyro_lambda", GyroLambdaOpt, DEFAULTS["gyro_lambda"]),
    ("gyro_bias", GyroBiasOpt, DEFAULTS["gyro_bias"]),
    ("optimise_gyro_bias", OptimiseGyroBiasOpt, DEFAULTS["optimise_gyro_bias"]),
    ("gyro_sensitivity", GyroSensitivityOpt, DEFAULTS["gyro_sensitivity"]))


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


def pick(options: dict[str, Any], group: tuple) -> dict[str, Any]:
    return {name: options[name] for name, _, _ in group}


def build_settings(*, window, min_len, k, init, init_start, init_end, statistic,
                   single_segment, split_alpha, delta, min_blocks, g, lam, lambdas, points,
                   n_select, n_group, gyro_lambda, gyro_bias, optimise_gyro_bias, gyro_sensitivity
                   ) -> dict[str, Any]:
    """The options as keyword arguments of imucal.calibrate (every key of Settings)."""
    if init is not None and (init_start is not None or init_end is not None):
        raise usage_error("give the initial interval either as --init START END or as "
                          "--init-start/--init-end, not both", "'--init'")
    start, end = init if init is not None else THESIS_INIT
    start = start if init_start is None else init_start
    end = end if init_end is None else init_end
    if not (math.isfinite(start) and math.isfinite(end) and 0 <= start < end):
        raise usage_error(f"the initial still interval must satisfy 0 <= START < END, got "
                          f"{start:g} {end:g}", "'--init'")
    given = init is not None or init_start is not None or init_end is not None
    return {"window": window, "min_len": min_len, "k": k, "init": (start, end) if given else None,
            "statistic": statistic, "single_segment": single_segment,
            "split_alpha": split_alpha, "delta": delta,
            "min_blocks": min_blocks, "g": g, "lam": lam if lam == "auto" else float(lam),
            "lambdas": DEFAULTS["lambdas"] if lambdas is None else _lambdas(lambdas),
            "points": points, "n_select": n_select, "n_group": n_group,
            "gyro_lambda": gyro_lambda, "gyro_bias": gyro_bias,
            "optimise_gyro_bias": optimise_gyro_bias, "gyro_sensitivity": gyro_sensitivity}


def load_kwargs(*, gyro, rate, acc_unit, gyro_unit, columns, time_unit, acc_only=False,
                spill_dir=None, acc=None, mag=None, temp=None) -> dict[str, Any]:
    spill = None
    if spill_dir is not None:  # imported only then: it imports numpy (not for --help, nor
        from imucal.io.spill import SpillPolicy  # for opening a saved .rrd)

        spill = SpillPolicy(directory=spill_dir)
    # --gyro names a file where one is there, else a log's stream (a table's missing gyroscope
    # file is then said by the loader).
    gyro_file = gyro if gyro is not None and Path(gyro).exists() else None
    select = {"acc": acc, "gyro": None if gyro_file is not None else gyro, "mag": mag,
              "temp": temp}
    return {"gyro_path": None if gyro_file is None else Path(gyro_file), "rate": rate,
            "select": {k: v for k, v in select.items() if v is not None} or None,
            "acc_unit": acc_unit, "gyro_unit": gyro_unit,
            "columns": parse_columns(columns), "time_unit": time_unit, "acc_only": acc_only,
            "spill": spill}


def usage_error(message: str, hint: str) -> typer.BadParameter:
    """A usage error (exit 2) found after parsing, shown like click's own."""
    ctx = typer.main.get_current_context(silent=True)
    return typer.BadParameter(message, ctx=ctx, param_hint=hint)
