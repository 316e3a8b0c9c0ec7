"""What the commands share around a run: progress lines, output-path checks, the viewer's
import."""

from __future__ import annotations

import contextlib
import math
import sys
import time
from collections.abc import Iterator
from pathlib import Path

from imucal.errors import ImucalError

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


def check_outputs(outputs: list[Path | str | None], inputs: list[Path | str | None]
                  ) -> list[Path]:
    """Refuse bad output paths before any work (see imucal.io.atomic.check_output_path: a
    missing directory, an input, a directory, a device or FIFO, a read-only file, ...) and the
    same file given for two outputs."""
    from imucal.io.atomic import Transaction

    Transaction(outputs, inputs=inputs)  # checks only: nothing is locked or written
    return [Path(o) for o in outputs if o is not None]


def check_inputs(inputs: list[Path | str | None]) -> None:
    """A symbolic-link loop as an input is the user's: one line, not a traceback."""
    import errno
    import os

    for inp in inputs:
        if inp is None:
            continue
        try:
            os.stat(inp)
        except OSError as e:
            if e.errno == errno.ELOOP:
                raise ImucalError("is a loop of symbolic links", source=str(inp)) from None


# The fits square |g| and weigh squared parameters by lambda (method.md M2, M3): past these
# magnitudes double precision overflows (or underflows to zero) before the first step, which
# the fit can only report as a non-finite cost. 1e150 squared is still a finite double.
MAGNITUDE = 1e150
# (option, flag, smallest): a scale (|g|, counts per unit) is divided by as well; a lambda
# as small as you like only stops weighing.
_MAGNITUDE_OPTIONS = (("g", "--g", 1 / MAGNITUDE), ("gyro_sensitivity", "--gyro-sensitivity",
                      1 / MAGNITUDE), ("lam", "--lambda", 0.0),
                      ("gyro_lambda", "--gyro-lambda", 0.0), ("lambdas", "--lambdas", 0.0))


def check_magnitudes(settings: dict) -> None:
    """A usage error (exit 2) for a scale no fit can compute with, e.g. ``--g 1e-300``."""
    from imucal.cli.options import usage_error

    for key, flag, smallest in _MAGNITUDE_OPTIONS:
        value = settings.get(key)
        for v in value if isinstance(value, (tuple, list)) else (value,):
            if v is None or v == "auto":
                continue
            if not smallest <= abs(float(v)) <= MAGNITUDE:
                span = f"{smallest:g} to {MAGNITUDE:g}" if smallest else f"at most {MAGNITUDE:g}"
                raise usage_error(f"{float(v):g} is beyond what the fit can compute with in "
                                  f"double precision ({span})", f"'{flag}'")


def gyro_sidecar(path: Path) -> Path:
    """Where write_calibrated puts the gyroscope when it does not share the accelerometer's
    timestamps (CSV/Parquet only)."""
    return path.with_name(path.stem + ".gyro" + path.suffix)


def fmt(x: float | None, spec: str = ".3g") -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "n/a"
    return format(x, spec)


def fmt_vec(values, spec: str = ".6g") -> str:
    return " ".join(format(float(v), spec) for v in values)


def fmt_rate(hz: float | None) -> str:
    return "n/a" if hz is None else f"{hz:.4g} Hz"


def written_tables(path: Path, cal) -> list[str]:
    side = gyro_sidecar(path)
    if path.suffix.lower() != ".mat" and cal.gyro is not None and side.exists():
        import numpy as np

        if not np.array_equal(cal.t_acc, cal.t_gyro):
            return [str(path), str(side)]
    return [str(path)]


def write_signals(tx, path: str, signals) -> None:
    """:func:`imucal.io.export.write_calibrated` into the transaction ``tx``: the table, and
    its gyroscope sidecar (``cal.gyro.csv``) when the gyroscope has timestamps of its own.
    When it has not, a sidecar left by a previous run is removed at commit: it would be read
    as this run's gyroscope (``tx.removed`` names it)."""
    from imucal.io.export import write_calibrated

    with tx.writing(path) as tmp:
        if Path(path).suffix.lower() != ".mat":
            tx.expect(gyro_sidecar(Path(path)), gyro_sidecar(tmp))
        write_calibrated(tmp, signals)


def removed_lines(removed: list[str], signals) -> list[str]:
    why = ("this run writes no gyroscope" if signals.gyro is None else
           "this run's gyroscope shares the accelerometer's timestamps and is in the table")
    return [f"removed {r} (a previous run's gyroscope table; {why})" for r in removed]


@contextlib.contextmanager
def viewer_available() -> Iterator[None]:
    """Around the (lazy) import of the viewer: a missing rerun-sdk is a one-line error that
    says what to install, not a traceback."""
    try:
        yield
    except ModuleNotFoundError as e:
        if e.name and e.name.split(".")[0] == "rerun":
            why = "rerun-sdk is not installed (pip install 'rerun-sdk==0.41.0')"
        else:
            why = f"module {e.name!r} not found"
        raise ImucalError(f"the viewer is not available: {why}", source="viewer") from None
