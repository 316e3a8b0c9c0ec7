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


def check_outputs(outputs: list[Path | None], inputs: list[Path | None]) -> list[Path]:
    """Refuse bad output paths before any work: missing directory, an input, or a duplicate."""
    from imucal.io.atomic import check_output_path

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
