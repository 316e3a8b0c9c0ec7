"""Which variables of a MATLAB file hold time, the accelerometer and the gyroscope
(method.md §0): by name (acc, gyro, t_acc, ...), or one matrix read by position."""

from __future__ import annotations

import numpy as np

from imucal.errors import ImucalError
from imucal.io.column_names import LABELS
from imucal.io.file_contents import Table, Variables
from imucal.io.parts import LoadOptions, Part, columns_for
from imucal.io.table_layout import expected, from_positions, widths

_ACC_VARS = ("acc", "accel", "acceleration", "accelerometer", "a", "acc_data")
_GYRO_VARS = ("gyro", "gyr", "gyroscope", "w", "omega", "gyro_data")
_OWN_TIME_VARS = {"acc": ("t_acc", "time_acc", "t_a"), "gyro": ("t_gyro", "t_gyr", "time_gyro",
                                                               "t_w")}
_SHARED_TIME_VARS = ("t", "time", "timestamp", "timestamps")


def from_variables(content: Variables, sensors: tuple[str, ...],
                    opts: LoadOptions) -> dict[str, Part]:
    source, variables = content.source, content.arrays
    lower = {name.lower(): name for name in variables}
    found = {s: _find_var(lower, names, LABELS[s], source)
             for s, names in (("acc", _ACC_VARS), ("gyro", _GYRO_VARS))}
    for sensor, names in (("acc", _ACC_VARS), ("gyro", _GYRO_VARS)):
        if sensor in sensors and found[sensor] is None:
            _not_numbers(content, names, LABELS[sensor])
    shared = _find_var(lower, _SHARED_TIME_VARS, "time", source)
    shared_t = _vector(variables, shared, source) if shared else None

    if not any(found[s] for s in sensors):
        return _single_matrix(content, sensors, shared, shared_t, opts)
    if columns_for(opts, sensors, source):
        raise ImucalError("--columns applies to tables; this .mat file holds named variables",
                          source=source, field="columns")
    if found["acc"] is None and "acc" in sensors:
        raise ImucalError(f"no accelerometer variable (expected one of {', '.join(_ACC_VARS)}); "
                          f"found {', '.join(variables)}", source=source, field="acc")
    parts = {}
    for sensor in sensors:
        name = found[sensor]
        if name is None:
            continue
        values = _orient(variables[name], (3, 4), f"variable {name!r}", source,
                         "3 x N or N x 3 (or 4 with time)")
        part = Part(sensor, source, values[:, -3:])
        own = _find_var(lower, _OWN_TIME_VARS[sensor], "time", source)
        if values.shape[1] == 4:
            part.time, part.time_label = values[:, 0], f"variable {name!r} (first column)"
        elif own is not None:
            part.time, part.time_label = _vector(variables, own, source), f"variable {own!r}"
        elif shared_t is not None:
            part.time, part.time_label = shared_t, f"variable {shared!r}"
        if part.time is not None and part.time.size != len(part.values):
            raise ImucalError(f"{part.time_label} has {part.time.size} values but {name!r} has "
                              f"{len(part.values)} samples", source=source,
                              field="time")
        parts[sensor] = part
    return parts


def _not_numbers(content: Variables, names: tuple[str, ...], label: str) -> None:
    """A variable named as a sensor's that holds something else than real numbers (complex,
    sparse, text, a cell): said as such, not as a missing variable (issue 27)."""
    for name, what in content.skipped.items():
        if name.lower() in names:
            raise ImucalError(f"the variable {name!r} holds {what}, not real numbers; the "
                              f"{label} is expected as a real 3 x N or N x 3 matrix (full, "
                              "double or integer)", source=content.source, field=name)


def _find_var(lower: dict[str, str], names: tuple[str, ...], what: str, source: str) -> str | None:
    hits = [lower[n] for n in names if n in lower]
    if len(hits) > 1:
        raise ImucalError(f"variables {', '.join(map(repr, hits))} all look like {what} data; "
                          "keep one", source=source, field=what)
    return hits[0] if hits else None


def _vector(variables: dict[str, np.ndarray], name: str, source: str) -> np.ndarray:
    arr = variables[name]
    if min(arr.shape) != 1:
        raise ImucalError(f"time variable {name!r} has shape {arr.shape[0]} x {arr.shape[1]}; "
                          "expected a vector", source=source, field="time")
    return arr.ravel()


def _orient(matrix: np.ndarray, widths: tuple[int, ...], what: str, source: str,
            expected: str) -> np.ndarray:
    """Samples along rows. A side of an allowed width is the channel axis; when both sides
    qualify, samples run along the longer one."""
    rows, cols = matrix.shape
    if cols in widths and (rows not in widths or rows >= cols):
        return matrix
    if rows in widths:
        return matrix.T
    raise ImucalError(f"{what} has shape {rows} x {cols}; expected {expected}", source=source,
                      field="shape")


def _single_matrix(content: Variables, sensors: tuple[str, ...], shared: str | None,
                   shared_t: np.ndarray | None, opts: LoadOptions) -> dict[str, Part]:
    source = content.source
    matrices = {n: m for n, m in content.arrays.items() if min(m.shape) > 1}
    if not matrices:
        raise ImucalError("no numeric matrix found; expected one N x 6 matrix (ax ay az gx gy gz) "
                          "or variables named acc and gyro", source=source)
    if len(matrices) > 1:
        raise ImucalError(f"several matrices ({', '.join(matrices)}) and none named like acc or "
                          "gyro; expected one matrix or variables acc, gyro", source=source,
                          field="variables")
    (name, matrix), = matrices.items()
    matrix = _orient(matrix, widths(sensors), f"matrix {name!r}", source, expected(sensors))
    table = Table(source, None, matrix.shape[1], lambda i: matrix[:, i],
                   shared_time=shared_t, shared_time_name=shared or "")
    return from_positions(table, sensors, opts)
