"""Read a recording into a :class:`~imucal.session.Session` (method.md §0).

:mod:`imucal.io.readers` recognises the format and reads the file into a table of columns or named
variables; this module decides which of them hold time, the accelerometer and the gyroscope
(by name, by position or as the user says), settles the time base and the units, and bridges
short runs of missing samples.

Every problem a user can cause becomes an :class:`~imucal.errors.ImucalError` naming the file,
the field and what was expected; exceptions of the parsing libraries never escape.
"""

from __future__ import annotations

import hashlib
import math
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from imucal.errors import ImucalError, plural
from imucal.io.file_contents import Table, Variables
from imucal.io.readers import display_name, read_file
from imucal.session import Session

__all__ = ["load_session"]

MAX_FILE_BYTES = 2 * 1024**3
MAX_RATE_HZ = 100_000.0
MAX_BRIDGED_RUN = 5  # longest run of non-finite samples that is interpolated instead of refused
MAX_BRIDGED_FRACTION = 0.05  # and at most this share of a recording may be interpolated

TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
ROLES = ("t", "ax", "ay", "az", "gx", "gy", "gz")
AXES = {"acc": ("ax", "ay", "az"), "gyro": ("gx", "gy", "gz")}
LABELS = {"acc": "accelerometer", "gyro": "gyroscope"}

_CHUNK = 1 << 20

# --- unit spellings (arguments and hints in column names share one table) -------------------


def _unit_key(text: str) -> str:
    """'m/s^2' -> 'ms2', 'deg/s' -> 'degs', '°/s' -> 'degs', 'µs' -> 'us'."""
    text = text.strip().lower().replace("°", "deg").replace("²", "2")
    text = text.replace("µ", "u").replace("μ", "u")
    return re.sub(r"[^a-z0-9]", "", text)


_ACC_UNIT_KEYS = {
    "g": "g", "ms2": "m/s^2", "mss": "m/s^2", "mps2": "m/s^2", "msec2": "m/s^2",
    "counts": "counts", "count": "counts", "raw": "counts", "lsb": "counts", "adc": "counts",
}
_GYRO_UNIT_KEYS = {
    "rads": "rad/s", "radpers": "rad/s", "degs": "deg/s", "dps": "deg/s", "degpers": "deg/s",
    "counts": "counts", "count": "counts", "raw": "counts", "lsb": "counts", "adc": "counts",
}
_TIME_UNIT_KEYS = {
    "s": "s", "sec": "s", "secs": "s", "second": "s", "seconds": "s",
    "ms": "ms", "msec": "ms", "millis": "ms", "us": "us", "usec": "us", "micros": "us",
    "ns": "ns", "nsec": "ns", "nanos": "ns",
}

# --- column-name spellings, compared with case and punctuation removed ("Acc_X" -> "accx") ---

_ACC_PREFIXES = ("a", "acc", "accl", "accel", "acceleration", "accelerometer", "linacc",
                 "linearacceleration")
_GYRO_PREFIXES = ("g", "w", "gyr", "gyro", "gyroscope", "omega", "angvel", "angularvelocity",
                  "angularrate")
_TIME_NAMES = ("t", "ts", "time", "times", "timestamp", "timestamps", "seconds", "sec",
               "elapsed", "elapsedtime", "timesec",
               "zeit", "tiempo", "temps", "tempo", "tid")  # de, es, fr, it/pt, sv/da/no
# Sample counters look like time (increasing numbers) but are not: never use them as time.
_COUNTER_NAMES = ("n", "nsample", "nsamples", "sample", "samples", "samplenumber", "samplenr",
                  "sampleindex", "sampleidx", "samplecounter", "index", "idx", "counter", "count",
                  "frame", "framenumber", "seq", "sequence", "packetcounter")


def _build_name_table() -> dict[str, str]:
    table: dict[str, str] = {}
    for sensor, prefixes in (("a", _ACC_PREFIXES), ("g", _GYRO_PREFIXES)):
        for prefix in prefixes:
            for axis in "xyz":
                table[prefix + axis] = sensor + axis
                if len(prefix) > 1:  # "x_acc" yes, "xa" no
                    table[axis + prefix] = sensor + axis
    table.update({name: "t" for name in _TIME_NAMES})
    table.update({name: "counter" for name in _COUNTER_NAMES})
    return table


_NAME_TABLE = _build_name_table()


@dataclass(frozen=True)
class _ColumnMeaning:
    role: str | None  # one of ROLES, "counter", or None (not understood)
    unit: str | None = None  # canonical unit from the name, if it carried a valid one


def _classify_name(name: str, single_sensor: str | None) -> _ColumnMeaning:
    """Meaning of a column name; ``single_sensor`` lets a per-sensor file call axes x, y, z."""
    text = name.strip().strip("\"'").lower()
    bracket_unit = None
    match = re.search(r"[(\[{]([^)\]}]*)[)\]}]\s*$", text)  # "Acc X (m/s^2)", "time [ms]"
    if match:
        bracket_unit = _unit_key(match.group(1))
        text = text[: match.start()]
    tokens = re.findall(r"[a-z0-9]+", _unit_key_spaced(text))
    generic = {}  # plain x, y, z only mean something in a file holding one sensor
    if single_sensor is not None:
        generic = dict(zip("xyz", AXES[single_sensor], strict=True))
    # Try the whole name first, then peel 1-3 trailing tokens off as a unit ("acc_x_m_s2").
    for k in range(0, min(3, len(tokens) - 1) + 1):
        base = "".join(tokens[: len(tokens) - k])
        unit = "".join(tokens[len(tokens) - k :]) if k else bracket_unit
        role = _NAME_TABLE.get(base) or generic.get(base)
        if role is None:
            continue
        canonical = _unit_for_role(role, unit)
        if k == 0 or canonical is not None:
            return _ColumnMeaning(role, canonical)
    return _ColumnMeaning(None)


def _unit_key_spaced(text: str) -> str:
    """Like :func:`_unit_key` but keeps token boundaries ("acc_x_m/s^2" -> "acc x m s 2")."""
    text = text.replace("°", "deg").replace("²", "2").replace("µ", "u").replace("μ", "u")
    return re.sub(r"[^a-z0-9]+", " ", text)


def _unit_for_role(role: str, unit: str | None) -> str | None:
    if unit is None:
        return None
    if role in AXES["acc"]:
        return _ACC_UNIT_KEYS.get(unit)
    if role in AXES["gyro"]:
        return _GYRO_UNIT_KEYS.get(unit)
    if role == "t":
        return _TIME_UNIT_KEYS.get(unit)
    return None


# --- what the loader builds from them -------------------------------------------------------------


@dataclass
class _Part:
    """One sensor's samples as read from a file, before time and units are settled."""

    sensor: str  # "acc" or "gyro"
    source: str
    values: np.ndarray  # (N, 3) float64
    time: np.ndarray | None = None  # in the file's units
    time_label: str = ""
    time_unit: str | None = None  # named by the file (e.g. a column "time_ms")
    time_is_datetime: bool = False  # converted from date-times: seconds whatever time_unit says
    unit_hint: str | None = None
    counter_label: str | None = None  # a sample-counter column, to explain a missing rate
    looks_like_counter: bool = False  # positional time column holding 0, 1, 2, ...


@dataclass
class _Options:
    rate: float | None
    time_unit: str
    columns: dict[str, str | int] | None
    notes: list[str] = field(default_factory=list)


# --- public API ----------------------------------------------------------------------------------


def load_session(
    path: str | os.PathLike[str],
    *,
    gyro_path: str | os.PathLike[str] | None = None,
    rate: float | None = None,
    acc_unit: str = "auto",
    gyro_unit: str = "auto",
    columns: Mapping[str, str | int] | None = None,
    time_unit: str = "s",
    acc_only: bool = False,
) -> Session:
    """Load an accelerometer + gyroscope recording from ``path`` (and ``gyro_path``).

    ``rate`` (Hz) supplies timestamps for files without a time column; ``time_unit`` is the unit
    of a time column ("s", "ms", "us", "ns"). ``acc_unit`` is "auto", "g", "m/s^2" or "counts";
    ``gyro_unit`` is "auto", "rad/s", "deg/s" or "counts" (deg/s is converted to rad/s).
    ``columns`` maps roles {"t","ax","ay","az","gx","gy","gz"} to column names, or to 0-based
    positions for a file without a header. A file with an accelerometer and no gyroscope is
    refused unless ``acc_only`` says an accelerometer-only session is meant (three columns are
    as often one half of a two-file session); ``acc_only`` also drops a gyroscope that is there.
    Raises :class:`ImucalError` for any bad input.
    """
    paths = [Path(path)] + ([Path(gyro_path)] if gyro_path is not None else [])
    source = " + ".join(display_name(p) for p in paths)
    opts = _Options(
        rate=_check_rate(rate, source),
        time_unit=_check_choice(time_unit, _TIME_UNIT_KEYS, "time_unit", source),
        columns=_check_columns(columns, source),
    )
    acc_unit = _check_unit_arg(acc_unit, _ACC_UNIT_KEYS, "acc_unit", source)
    gyro_unit = _check_unit_arg(gyro_unit, _GYRO_UNIT_KEYS, "gyro_unit", source)
    for p in paths:
        _check_file(p)

    if gyro_path is None:
        parts = _extract(read_file(paths[0]), ("acc", "gyro"), opts)
        if "gyro" not in parts and not acc_only:
            raise ImucalError("found an accelerometer and no gyroscope; give the gyroscope's "
                              "file with --gyro FILE, or --acc-only to calibrate the "
                              "accelerometer alone", source=source, field="columns")
        if acc_only:
            parts.pop("gyro", None)
            opts.notes.append(f"accelerometer only (--acc-only): {display_name(paths[0])}")
    else:
        parts = _extract(read_file(paths[0]), ("acc",), opts)
        parts.update(_extract(read_file(paths[1]), ("gyro",), opts))
    if gyro_path is None and "gyro" in parts:
        _own_rows(parts["acc"], parts["gyro"], opts)

    acc, t_acc = _settle_time(parts["acc"], opts)
    gyro = t_gyro = None
    if "gyro" in parts:
        gyro, t_gyro = _settle_time(parts["gyro"], opts)

    acc_unit = _resolve_acc_unit(acc, acc_unit, parts["acc"], opts.notes)
    final_gyro_unit = None
    if gyro is not None:
        gyro_unit = _resolve_gyro_unit(gyro, gyro_unit, parts["gyro"].unit_hint, acc_unit, opts)
        if gyro_unit == "deg/s":
            gyro = np.deg2rad(gyro)
            opts.notes.append("gyroscope converted from deg/s to rad/s")
            gyro_unit = "rad/s"
        final_gyro_unit = gyro_unit

    return Session(
        acc=np.ascontiguousarray(acc, dtype=np.float64),
        t_acc=np.ascontiguousarray(t_acc, dtype=np.float64),
        gyro=None if gyro is None else np.ascontiguousarray(gyro, dtype=np.float64),
        t_gyro=None if t_gyro is None else np.ascontiguousarray(t_gyro, dtype=np.float64),
        acc_unit=acc_unit,
        gyro_unit=final_gyro_unit,
        source=source,
        sha256=_sha256(paths),
        notes=tuple(dict.fromkeys(opts.notes)),  # a shared time column speaks once
    )


# --- argument checks -----------------------------------------------------------------------------


def _check_rate(rate: float | None, source: str) -> float | None:
    if rate is None:
        return None
    try:
        value = float(rate)
    except (TypeError, ValueError):
        raise ImucalError(f"sample rate must be a number of Hz, got {rate!r}",
                          source=source, field="rate") from None
    if not math.isfinite(value) or value <= 0 or value > MAX_RATE_HZ:
        raise ImucalError(
            f"sample rate must be a finite number of Hz in (0, {MAX_RATE_HZ:g}], got {rate!r}",
            source=source, field="rate",
        )
    return value


def _check_choice(value: str, keys: Mapping[str, str], name: str, source: str) -> str:
    canonical = keys.get(_unit_key(value)) if isinstance(value, str) else None
    if canonical is None:
        choices = ", ".join(sorted(set(keys.values())))
        raise ImucalError(f"expected one of {choices}, got {value!r}", source=source, field=name)
    return canonical


def _check_unit_arg(value: str, keys: Mapping[str, str], name: str, source: str) -> str:
    if isinstance(value, str) and value.strip().lower() == "auto":
        return "auto"
    return _check_choice(value, {**keys, "auto": "auto"}, name, source)


def _check_columns(columns: Mapping[str, str | int] | None, source: str) -> dict | None:
    if columns is None:
        return None
    if not isinstance(columns, Mapping):
        raise ImucalError("expected a mapping of role to column name, e.g. {'ax': 'acc_x'}",
                          source=source, field="columns")
    unknown = [k for k in columns if k not in ROLES]
    if unknown:
        raise ImucalError(f"unknown role(s) {', '.join(map(repr, unknown))}; expected keys from "
                          f"{', '.join(ROLES)}", source=source, field="columns")
    for role, col in columns.items():
        ok = isinstance(col, str) or (isinstance(col, int) and not isinstance(col, bool))
        if not ok or (isinstance(col, int) and col < 0):
            raise ImucalError(f"{role!r} must map to a column name or a 0-based position, "
                              f"got {col!r}", source=source, field="columns")
    return dict(columns)


def _columns_for(opts: _Options, sensors: tuple[str, ...], source: str) -> dict[str, str | int]:
    """The part of ``columns`` that concerns this file: in a two-file session the accelerometer
    file takes t, ax, ay, az and the gyroscope file t, gx, gy, gz."""
    roles = {"t", *(r for s in sensors for r in AXES[s])}
    mine = {role: col for role, col in (opts.columns or {}).items() if role in roles}
    values = list(mine.values())
    dupes = sorted({str(v) for v in values if values.count(v) > 1})
    if dupes:
        raise ImucalError(f"column(s) {', '.join(dupes)} mapped to more than one role",
                          source=source, field="columns")
    return mine


def _check_file(path: Path) -> None:
    name = display_name(path)
    try:
        st = path.stat()
    except FileNotFoundError:
        where = "" if str(path) == name else f" (looked at {path})"
        raise ImucalError(f"file not found{where}", source=name) from None
    except OSError as exc:
        raise ImucalError(f"cannot access the file ({exc.strerror})", source=name) from None
    if path.is_dir():
        raise ImucalError("is a directory; expected a data file", source=name)
    if st.st_size == 0:
        raise ImucalError("the file is empty; expected IMU samples", source=name)
    if st.st_size > MAX_FILE_BYTES:
        raise ImucalError(f"the file is {st.st_size / 2**30:.1f} GiB; files over 2 GiB are not "
                          "loaded (split the recording)", source=name)


def _sha256(paths: list[Path]) -> str:
    digest = hashlib.sha256()
    for p in paths:
        with p.open("rb") as fh:
            while chunk := fh.read(_CHUNK):
                digest.update(chunk)
    return digest.hexdigest()


# --- from a file's contents to one part per sensor ----------------------------------------------


def _extract(content: Table | Variables, sensors: tuple[str, ...],
             opts: _Options) -> dict[str, _Part]:
    if isinstance(content, Variables):
        return _from_variables(content, sensors, opts)
    if content.names is None:
        return _from_positions(content, sensors, opts)
    return _from_names(content, sensors, opts)


def _widths(sensors: tuple[str, ...]) -> tuple[int, ...]:
    return (3, 4, 6, 7) if len(sensors) == 2 else (3, 4)


def _expected(sensors: tuple[str, ...]) -> str:
    if len(sensors) == 2:
        return ("6 columns (ax ay az gx gy gz), 7 (t + 6), or 3/4 for an accelerometer-only "
                "session")
    xyz = "x y z"
    return f"3 columns ({xyz} of the {LABELS[sensors[0]]}) or 4 (t {xyz})"


def _from_positions(table: Table, sensors: tuple[str, ...], opts: _Options) -> dict[str, _Part]:
    """Headerless text or one matrix: columns [t] ax ay az [gx gy gz] by position."""
    source = table.source
    columns = _columns_for(opts, sensors, source)
    if columns:
        mapping = {}
        for role, col in columns.items():
            if not isinstance(col, int):
                raise ImucalError(f"the file has no header, so {role!r} must be a 0-based "
                                  f"column position, got {col!r}", source=source,
                                  field="columns")
            if col >= table.n_cols:
                raise ImucalError(f"{role!r} -> position {col}, but the file has only "
                                  f"{table.n_cols} columns", source=source,
                                  field="columns")
            mapping[role] = col
        return _parts_from_mapping(table, mapping, sensors, opts, counter=None)
    n = table.n_cols
    if n not in _widths(sensors):
        raise ImucalError(f"found {n} column(s); expected {_expected(sensors)}", source=source,
                          field="columns")
    offset = 1 if n in (4, 7) else 0
    mapping = {"t": 0} if offset else {}
    roles = AXES[sensors[0]] + (AXES["gyro"] if n >= 6 else ())
    mapping.update({role: offset + i for i, role in enumerate(roles)})
    parts = _parts_from_mapping(table, mapping, sensors, opts, counter=None)
    if offset:
        for part in parts.values():
            part.looks_like_counter = _is_counter(part.time)
    return parts


def _is_counter(values: np.ndarray | None) -> bool:
    if values is None or values.size < 2 or not np.isfinite(values).all():
        return False
    return bool(np.all(np.diff(values) == 1) and float(values[0]).is_integer())


def _from_names(table: Table, sensors: tuple[str, ...], opts: _Options) -> dict[str, _Part]:
    """A table with a header: map column names to roles, then let ``columns`` override."""
    assert table.names is not None
    single = sensors[0] if len(sensors) == 1 else None
    wanted = {"t", *(r for s in sensors for r in AXES[s])}
    mapping: dict[str, int] = {}
    units: dict[str, str | None] = {}
    counter = None
    explicit = _explicit_columns(table, _columns_for(opts, sensors, table.source))
    taken = set(explicit.values())
    for i, name in enumerate(table.names):
        if i in taken:
            continue
        meaning = _classify_name(name, single)
        if meaning.role == "counter":
            counter = counter or table.label(i)
        elif meaning.role in wanted and meaning.role not in explicit:
            if meaning.role in mapping:
                other = table.names[mapping[meaning.role]]
                raise ImucalError(f"columns {other!r} and {name!r} both look like {meaning.role!r}"
                                  f"; choose one with columns={{{meaning.role!r}: ...}}",
                                  source=table.source, field="columns")
            mapping[meaning.role] = i
            units[meaning.role] = meaning.unit
    for role, i in explicit.items():  # a unit in an explicitly mapped name still counts
        meaning = _classify_name(table.names[i], single)
        units[role] = meaning.unit if meaning.role == role else None
    mapping.update(explicit)
    used = set(mapping.values())
    ignored = [n for i, n in enumerate(table.names) if i not in used and n]
    parts = _parts_from_mapping(table, mapping, sensors, opts, counter)
    if ignored and parts:
        opts.notes.append(f"ignored columns in {table.source}: {', '.join(ignored)}")
    for sensor, part in parts.items():
        hints = {units.get(role) for role in AXES[sensor]}
        part.unit_hint = hints.pop() if len(hints) == 1 else None
        if "t" in mapping and units.get("t"):
            part.time_unit = units["t"]
    return parts


def _explicit_columns(table: Table, columns: dict[str, str | int]) -> dict[str, int]:
    """Column indices of the roles the user mapped by name (any case) or position."""
    assert table.names is not None
    lowered = [n.strip().lower() for n in table.names]
    result = {}
    for role, col in columns.items():
        if isinstance(col, int):
            if col >= table.n_cols:
                raise ImucalError(f"{role!r} -> position {col}, but the file has only "
                                  f"{table.n_cols} columns", source=table.source,
                                  field="columns")
            result[role] = col
        elif col in table.names:
            result[role] = table.names.index(col)
        elif col.strip().lower() in lowered:
            result[role] = lowered.index(col.strip().lower())
        else:
            raise ImucalError(f"{role!r} -> {col!r}, but there is no such column; the file has "
                              f"{', '.join(table.names)}", source=table.source,
                              field="columns")
    return result


def _parts_from_mapping(table: Table, mapping: dict[str, int], sensors: tuple[str, ...],
                        opts: _Options, counter: str | None) -> dict[str, _Part]:
    parts = {}
    for sensor in sensors:
        roles = AXES[sensor]
        present = [r for r in roles if r in mapping]
        if not present:
            if sensor == "acc" or len(sensors) == 1:
                have = ", ".join(table.names) if table.names else f"{table.n_cols} unnamed"
                example = "x, y, z or " if len(sensors) == 1 else ""
                raise ImucalError(
                    f"no {LABELS[sensor]} columns found (columns: {have}); expected names like "
                    f"{example}{roles[0]}/{'acc_x' if sensor == 'acc' else 'gyr_x'}, or map "
                    "them with columns=", source=table.source, field="columns",
                )
            continue
        if len(present) < 3:
            missing = [r for r in roles if r not in mapping]
            raise ImucalError(f"{LABELS[sensor]} columns incomplete: missing {', '.join(missing)}",
                              source=table.source, field="columns")
        values = np.column_stack([table.column(mapping[r]) for r in roles])
        part = _Part(sensor, table.source, values, counter_label=counter)
        if "t" in mapping:
            ti = mapping["t"]
            part.time = table.column(ti)
            part.time_label = table.label(ti)
            part.time_is_datetime = ti in table.seconds_cols
        elif table.shared_time is not None:
            part.time, part.time_label = table.shared_time, f"variable {table.shared_time_name!r}"
            if part.time.size != len(values):
                raise ImucalError(f"{part.time_label} has {part.time.size} values but the matrix "
                                  f"has {len(values)} samples", source=table.source,
                                  field="time")
        parts[sensor] = part
    return parts


# --- named MATLAB variables ----------------------------------------------------------------------

_ACC_VARS = ("acc", "accel", "acceleration", "accelerometer", "a", "acc_data")
_GYRO_VARS = ("gyro", "gyr", "gyroscope", "w", "omega", "gyro_data")
_OWN_TIME_VARS = {"acc": ("t_acc", "time_acc", "t_a"), "gyro": ("t_gyro", "t_gyr", "time_gyro",
                                                               "t_w")}
_SHARED_TIME_VARS = ("t", "time", "timestamp", "timestamps")


def _from_variables(content: Variables, sensors: tuple[str, ...],
                    opts: _Options) -> dict[str, _Part]:
    source, variables = content.source, content.arrays
    lower = {name.lower(): name for name in variables}
    found = {s: _find_var(lower, names, LABELS[s], source)
             for s, names in (("acc", _ACC_VARS), ("gyro", _GYRO_VARS))}
    shared = _find_var(lower, _SHARED_TIME_VARS, "time", source)
    shared_t = _vector(variables, shared, source) if shared else None

    if not any(found[s] for s in sensors):
        return _single_matrix(content, sensors, shared, shared_t, opts)
    if _columns_for(opts, sensors, source):
        raise ImucalError("columns= applies to tables; this .mat file holds named variables",
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
        part = _Part(sensor, source, values[:, -3:])
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
                   shared_t: np.ndarray | None, opts: _Options) -> dict[str, _Part]:
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
    matrix = _orient(matrix, _widths(sensors), f"matrix {name!r}", source, _expected(sensors))
    table = Table(source, None, matrix.shape[1], lambda i: matrix[:, i],
                   shared_time=shared_t, shared_time_name=shared or "")
    return _from_positions(table, sensors, opts)


# --- time and non-finite samples -----------------------------------------------------------------


def _own_rows(acc: _Part, gyro: _Part, opts: _Options) -> None:
    """Two sensors on rows of their own in one timed table (two logs merged on time: each row
    holds one sensor's values and leaves the other's empty): each sensor keeps its own rows.

    Only when many rows hold one sensor and not the other; a row missing both, or a few
    missing values, stay for the gap bridging (or its refusal) as before."""
    if (acc.time is None or gyro.time is None or len(acc.values) != len(gyro.values)
            or not (acc.time is gyro.time or np.array_equal(acc.time, gyro.time,
                                                            equal_nan=True))):
        return  # not rows of one table
    has_a = np.isfinite(acc.values).any(axis=1)
    has_g = np.isfinite(gyro.values).any(axis=1)
    n = len(has_a)
    one_only = np.count_nonzero(has_a != has_g)
    if one_only <= max(MAX_BRIDGED_RUN, MAX_BRIDGED_FRACTION * n):
        return
    for part, own in ((acc, has_a), (gyro, has_g)):
        part.values, part.time = part.values[own], part.time[own]
    opts.notes.append(f"{acc.source}: the accelerometer and the gyroscope are on rows of their "
                      f"own ({int(has_a.sum())} and {int(has_g.sum())} of {n}); each sensor "
                      "keeps its own rows and timestamps")


def _settle_time(part: _Part, opts: _Options) -> tuple[np.ndarray, np.ndarray]:
    """Checked timestamps in seconds (from the file, else the rate); short NaN gaps bridged."""
    label, source = LABELS[part.sensor], part.source
    values = part.values
    n = len(values)
    if n < 2:
        raise ImucalError(f"{label}: {n} sample(s); at least 2 are needed", source=source,
                          field="samples")
    time = part.time
    if time is not None and part.looks_like_counter and opts.time_unit == "s":
        # 0, 1, 2, ... in the time position is a sample counter (it would mean 1 Hz).
        if opts.rate is None:
            raise ImucalError(f"{part.time_label} looks like a sample counter (0, 1, 2, ...), "
                              "not time; a sample rate is needed (--rate HZ)", source=source,
                              field="rate")
        opts.notes.append(f"{part.time_label} of {source} is a sample counter; timestamps from "
                          f"the rate {opts.rate:g} Hz")
        time = None
    if time is not None:
        unit = _time_unit(part, opts)
        if unit == "s" and part.time_unit is None and not part.time_is_datetime:
            unit = _unit_from_steps(time, part, opts)
        with np.errstate(over="ignore", invalid="ignore"):  # non-finite times are refused below
            t = time * TIME_UNITS[unit]
        if opts.rate is not None:
            opts.notes.append(f"{label} timestamps taken from {part.time_label} of {source}; "
                              "the given rate is not used")
    elif opts.rate is not None:
        t = np.arange(n, dtype=np.float64) / opts.rate
    else:
        why = f" ({part.counter_label} is a sample counter, not time)" if part.counter_label else ""
        raise ImucalError(f"{label}: no time column{why}; a sample rate is needed (--rate HZ)",
                          source=source, field="rate")
    _check_timestamps(t, label, source)
    values, t = _bridge_gaps(values, t, label, source, opts.notes)
    return values, t


def _time_unit(part: _Part, opts: _Options) -> str:
    """The user's time_unit, except that a unit named by the file wins over the default "s"."""
    if part.time_is_datetime:
        return "s"
    if part.time_unit is None or part.time_unit == opts.time_unit:
        return opts.time_unit
    if opts.time_unit == "s":
        opts.notes.append(f"{part.time_label} of {part.source} read in {part.time_unit}, as its "
                          "name says")
        return part.time_unit
    opts.notes.append(f"{part.time_label} of {part.source} looks like {part.time_unit} but "
                      f"time_unit={opts.time_unit} was given; using {opts.time_unit}")
    return opts.time_unit


def _unit_from_steps(time: np.ndarray, part: _Part, opts: _Options) -> str:
    """"s", unless that would put the samples more than a second apart: then the first of ms,
    us, ns that gives an IMU's rate (loggers write integer ms or ns timestamps, often since
    boot, under names like "timestamp" that say no unit)."""
    with np.errstate(invalid="ignore", over="ignore"):
        step = np.diff(time[: min(len(time), 100_001)])
    step = step[np.isfinite(step) & (step > 0)]
    if len(step) == 0:
        return "s"
    median = float(np.median(step))
    if median <= 1.0:
        return "s"
    for unit in ("ms", "us", "ns"):
        dt = median * TIME_UNITS[unit]
        if 1.0 / MAX_RATE_HZ <= dt <= 1.0:
            opts.notes.append(f"{part.time_label} of {part.source} read in {unit}: its median "
                              f"step {median:g} means {1.0 / dt:.4g} Hz in {unit}, "
                              f"{1.0 / median:.2g} Hz in seconds (set --time-unit to override)")
            return unit
    return "s"


def _check_timestamps(t: np.ndarray, label: str, source: str) -> None:
    finite = np.isfinite(t)
    if not finite.all():
        i = int(np.flatnonzero(~finite)[0])
        raise ImucalError(f"{label} timestamp at index {i} is {float(t[i])}; expected finite, "
                          "increasing times", source=source, field="time")
    with np.errstate(over="ignore", invalid="ignore"):
        step = np.diff(t)
    bad = np.flatnonzero(~(step > 0))
    if bad.size:
        i = int(bad[0]) + 1
        kind = "duplicated" if step[i - 1] == 0 else "not increasing"
        raise ImucalError(f"{label} timestamps {kind} at index {i} ({float(t[i - 1])!r} then "
                          f"{float(t[i])!r}); expected strictly increasing times",
                          source=source, field="time")


def _bridge_gaps(values: np.ndarray, t: np.ndarray, label: str, source: str,
                 notes: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Interpolate short runs of non-finite samples (a dropped packet) and drop short runs at
    either end, where there is nothing to interpolate from; refuse anything more."""
    bad = ~np.isfinite(values).all(axis=1)
    if not bad.any():
        return values, t
    n, n_bad = len(values), int(bad.sum())
    step = np.diff(bad.view(np.int8), prepend=np.int8(0), append=np.int8(0))
    starts, ends = np.flatnonzero(step == 1), np.flatnonzero(step == -1)
    lengths = ends - starts
    first = f"{label}: {n_bad} NaN/Inf samples, first at index {int(starts[0])}"
    if lengths.max() > MAX_BRIDGED_RUN:
        j = int(np.argmax(lengths))
        raise ImucalError(f"{first}; the gap of {int(lengths[j])} at index {int(starts[j])} is "
                          f"longer than the {MAX_BRIDGED_RUN} samples that can be bridged",
                          source=source, field="samples")
    # Many short gaps would make the session largely made up: refuse rather than calibrate that.
    if n_bad > max(MAX_BRIDGED_RUN, MAX_BRIDGED_FRACTION * n):
        raise ImucalError(f"{first}; that is {n_bad / n:.1%} of the samples, more than the "
                          f"{MAX_BRIDGED_FRACTION:.0%} that can be bridged", source=source,
                          field="samples")
    head = int(ends[0]) if starts[0] == 0 else 0
    tail = int(starts[-1]) if ends[-1] == n else n
    if tail - head < 2:
        raise ImucalError(f"{first}; fewer than 2 finite samples remain", source=source,
                          field="samples")
    inner = bad.copy()
    inner[:head] = False
    inner[tail:] = False
    if inner.any():
        values = values.copy()
        good = ~bad
        for axis in range(values.shape[1]):
            values[inner, axis] = np.interp(t[inner], t[good], values[good, axis])
        gaps = [(int(a), int(b)) for a, b in zip(starts, ends, strict=True) if head <= a < tail]
        where = ", ".join(f"{a}-{b - 1}" if b - a > 1 else f"{a}" for a, b in gaps[:5])
        where += ", ..." if len(gaps) > 5 else ""
        notes.append(f"{label}: bridged {int(inner.sum())} NaN/Inf samples of {source} by linear "
                     f"interpolation in {plural(len(gaps), 'gap')} (index {where})")
    if head or tail < n:
        ends_named = " and ".join(w for w, hit in (("start", head), ("end", tail < n)) if hit)
        notes.append(f"{label}: dropped {head + n - tail} NaN/Inf samples at the {ends_named} "
                     f"of {source}")
    return values[head:tail], t[head:tail]


# --- units ---------------------------------------------------------------------------------------


def _integer_like(x: np.ndarray) -> bool:
    # Interpolated gaps are not integers; a few of them must not hide raw counts.
    return bool(np.mean(x == np.round(x)) >= 0.99)


def _guess_acc_unit(acc: np.ndarray) -> tuple[str | None, float]:
    with np.errstate(over="ignore", invalid="ignore"):
        norm = float(np.median(np.linalg.norm(acc, axis=1)))
        if 0.5 <= norm <= 2.0:
            return "g", norm
        if 5.0 <= norm <= 20.0:
            return "m/s^2", norm
        if float(np.median(np.abs(acc))) > 100 or (norm > 50 and _integer_like(acc)):
            return "counts", norm
    return None, norm


def _resolve_acc_unit(acc: np.ndarray, unit: str, part: _Part, notes: list[str]) -> str:
    guess, norm = _guess_acc_unit(acc)
    hint = part.unit_hint
    if unit != "auto":
        if guess is not None and guess != unit:
            notes.append(f"acc_unit {unit} given, but the median norm {norm:.4g} looks like "
                         f"{guess}")
        return unit
    if hint is not None:
        doubt = ""
        if guess not in (None, hint):
            doubt = f", though the median norm {norm:.4g} looks like {guess}"
        notes.append(f"accelerometer unit {hint} from the column names{doubt} (set --acc-unit to "
                     "override)")
        return hint
    if guess is None:
        raise ImucalError(
            f"cannot tell the accelerometer unit: median norm {norm:.4g} is not near 1 (g), "
            "9.8 (m/s^2) or raw counts; set --acc-unit", source=part.source, field="acc_unit",
        )
    notes.append(f"accelerometer unit guessed as {guess} from median norm {norm:.4g} (set "
                 "--acc-unit to override)")
    return guess


def _resolve_gyro_unit(gyro: np.ndarray, unit: str, hint: str | None, acc_unit: str,
                       opts: _Options) -> str:
    if unit != "auto":
        return unit
    if hint is not None:
        opts.notes.append(f"gyroscope unit {hint} from the column names (set --gyro-unit to "
                          "override)")
        return hint
    magnitude = np.abs(gyro)
    median = float(np.median(magnitude))
    p995 = float(np.percentile(magnitude, 99.5))
    if acc_unit == "counts" and median > 100 and _integer_like(gyro):
        guess, why = "counts", f"integer values with median |value| {median:.4g}"
    elif p995 > 20:
        guess, why = "deg/s", f"99.5th percentile of |w| {p995:.4g} (too fast for rad/s)"
    else:
        guess, why = "rad/s", f"99.5th percentile of |w| {p995:.4g}"
    opts.notes.append(f"gyroscope unit guessed as {guess} from {why} (set --gyro-unit to "
                      "override)")
    return guess
