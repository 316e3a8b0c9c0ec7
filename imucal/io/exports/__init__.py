"""Exports of a calibration file to the formats other tools read (``imucal export``).

One module per family: :mod:`imu_tk` (.calib triads), :mod:`fusion` (x-io Fusion C header),
:mod:`kalibr` (imu.yaml noise block and scale-misalignment intrinsics), :mod:`autopilot` (PX4
and ArduPilot parameter files), :mod:`c_header` (a dependency-free C implementation of the
whole model), :mod:`c_runtime` (a C99 runtime for the device: the
calibration, the still detector and the gyroscope bias's refresh), :mod:`plain` (JSON/YAML
with units). Each exporter takes the calibration read
back (:func:`read_export_input`), an output path and an optional segment, and returns the
files to write and what the conversion kept or lost.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from imucal.errors import ImucalError
from imucal.io.atomic import check_output_path, write_text_atomic
from imucal.io.exports.common import Exported, ExportInput, read_export_input


@dataclass(frozen=True)
class Format:
    module: str
    function: str
    default_name: str  # "{stem}" is the calibration file's stem
    description: str
    directory: bool = False  # the output is a directory the files are written into


FORMATS: dict[str, Format] = {
    "imu_tk": Format("imu_tk", "export", "{stem}.calib",
                     "imu_tk .calib triads (NAME_acc.calib, NAME_gyro.calib)"),
    "fusion": Format("fusion", "export", "{stem}_fusion.h", "x-io Fusion C header"),
    "kalibr": Format("kalibr", "export", "{stem}_kalibr.yaml",
                     "Kalibr imu.yaml: noise block and scale-misalignment intrinsics"),
    "px4": Format("autopilot", "px4", "{stem}_px4.params", "PX4 parameter file"),
    "ardupilot": Format("autopilot", "ardupilot", "{stem}_ardupilot.param",
                        "ArduPilot parameter file"),
    "c": Format("c_header", "export", "{stem}_imucal.h",
                "dependency-free C header applying the whole model"),
    "c_runtime": Format("c_runtime", "export", "{stem}_c_runtime",
                        "C99 runtime: calibration, still detector and gyroscope-bias refresh "
                        "(a directory: imucal_runtime.h, imucal_runtime.c)", directory=True),
    "json": Format("plain", "to_json", "{stem}_export.json", "plain JSON with units"),
    "yaml": Format("plain", "to_yaml", "{stem}_export.yaml", "plain YAML with units"),
}


# The formats that take calib.json's other triads and temperature models (method.md §11, §12).
CARRY_EXTRAS = ("px4", "ardupilot", "c", "json", "yaml")


def exporter(fmt: str) -> Callable[[ExportInput, Path, int | None], Exported]:
    spec = FORMATS.get(fmt)
    if spec is None:
        raise ImucalError(f"unknown format {fmt!r}; expected one of {', '.join(FORMATS)}",
                          field="--to")
    module = importlib.import_module(f"{__name__}.{spec.module}")
    return getattr(module, spec.function)


def default_output(calibration: Path, fmt: str) -> Path:
    return calibration.with_name(FORMATS[fmt].default_name.format(stem=calibration.stem))


def export(calibration: str | Path, fmt: str, out: str | Path | None = None, *,
           segment: int | None = None, noise: str | Path | None = None) -> Exported:
    """Export ``calibration`` (a calib.json) to ``fmt`` and write the files atomically."""
    calibration = Path(calibration)
    fn = exporter(fmt)
    inp = read_export_input(calibration, noise)
    target = Path(out) if out is not None else default_output(calibration, fmt)
    result = fn(inp, target, segment)
    if inp.extras is not None and fmt not in CARRY_EXTRAS:
        result.notes.append(f"the other triads and temperature models are not in {fmt} (only "
                            f"the reference triad's constant model): {', '.join(CARRY_EXTRAS)} "
                            "carry them")
    if FORMATS[fmt].directory:
        if target.exists() and not target.is_dir():
            raise ImucalError("expected a directory for the files, and a file of that name "
                              "exists", source=str(target), field="--out")
        target.mkdir(parents=True, exist_ok=True)
    inputs = (calibration,) + ((Path(noise),) if noise is not None else ())
    for path, _ in result.files:
        check_output_path(path, inputs)
    for path, text in result.files:
        write_text_atomic(path, text)
    return result


__all__ = ["FORMATS", "Exported", "ExportInput", "default_output", "export", "exporter",
           "read_export_input"]
