"""Read a recording into a :class:`~imucal.session.Session` (method.md §0): the front.

:mod:`imucal.io.readers` recognises the format and reads the file into a table of columns or named
variables; :mod:`~imucal.io.table_layout` and :mod:`~imucal.io.mat_layout` decide which of them
hold time, the accelerometer and the gyroscope (by name, by position or as the user says);
:mod:`~imucal.io.time_base` settles the time base and bridges short runs of missing samples;
:mod:`~imucal.io.units` settles the units.

Every problem a user can cause becomes an :class:`~imucal.errors.ImucalError` naming the file,
the field and what was expected; exceptions of the parsing libraries never escape.
"""

from __future__ import annotations

import hashlib
import math
import os
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from imucal.errors import ImucalError
from imucal.io.column_names import ALL_ROLES, LABELS
from imucal.io.file_contents import Table, Variables
from imucal.io.file_facts import FileFacts, read_facts
from imucal.io.input_files import check_file, check_gyro_file
from imucal.io.load_mat5_pool import usable_threads
from imucal.io.logs import check_select, choose_streams, log_format
from imucal.io.mat_layout import from_variables
from imucal.io.parts import LoadOptions, Part
from imucal.io.readers import display_name, read_file
from imucal.io.select import describe, find, parts_of
from imucal.io.spill import Spill, SpillPolicy, contiguous, elementwise
from imucal.io.table_layout import from_names, from_positions
from imucal.io.time_base import MAX_RATE_HZ, MIN_RATE_HZ, own_rows, settle_time
from imucal.io.units import (
    ACC_UNIT_KEYS,
    GYRO_UNIT_KEYS,
    SCALED_UNITS,
    TIME_UNIT_KEYS,
    check_choice,
    check_unit_arg,
    resolve_acc_unit,
    resolve_gyro_unit,
)
from imucal.session import Session
from imucal.stages.sanity import one_rate_pairing
from imucal.streams import UNITS, Stream, StreamSet
from imucal.warning import beside_note

__all__ = ["load_session"]

MAX_FILE_BYTES = 2 * 1024**3
# Said whenever a gyroscope read in deg/s is converted: a calibration file keeps it (among its
# warnings), and so knows its recording's unit (calibration_file.recorded_units).
DEG_S_NOTE = "gyroscope converted from deg/s to rad/s"

_CHUNK = 1 << 20


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
    spill: SpillPolicy | None = None,
    threads: int | None = None,
    select: Mapping[str, str | None] | None = None,
    number_samples: bool = False,
) -> Session:
    """Load an accelerometer + gyroscope recording from ``path`` (and ``gyro_path``).

    ``rate`` (Hz) supplies timestamps for files without a time column; ``time_unit`` is the unit
    of a time column ("s", "ms", "us", "ns"). ``acc_unit`` is "auto", "g", "m/s^2" or "counts";
    ``gyro_unit`` is "auto", "rad/s", "deg/s" or "counts" (deg/s is converted to rad/s).
    ``columns`` maps roles {"t","ax","ay","az","gx","gy","gz"} to column names, or to 0-based
    positions for a file without a header. A file with an accelerometer and no gyroscope is
    refused unless ``acc_only`` says an accelerometer-only session is meant (three columns are
    as often one half of a two-file session); ``acc_only`` also drops a gyroscope that is there.
    ``spill`` says where and from which size the signals of a .mat file are mapped from a
    temporary file rather than held in memory (:mod:`imucal.io.spill`; default: 64 MB and up,
    in the system's temporary folder). ``threads`` caps the threads that inflate a .mat file's
    variables (default: the cores the process may use; a batch worker passes 1, so that
    workers, not threads, use the cores). ``select`` names the streams to take from a log of
    many (a ROS bag, a ULog, a DataFlash log): {"acc": "/imu/data_raw", "gyro": ...}; without
    one the first IMU is taken and the choice said (:mod:`imucal.io.select`).
    ``number_samples``: a file with no time column and no rate is numbered (t = 0, 1, 2, ...,
    said in the notes) instead of refused, for a use that time cannot change (applying a
    calibration of one segment). Raises :class:`ImucalError` for any bad input.
    """
    paths = [Path(path)] + ([Path(gyro_path)] if gyro_path is not None else [])
    source = " + ".join(display_name(p) for p in paths)
    opts = LoadOptions(
        rate=_check_rate(rate, source),
        time_unit=check_choice(time_unit, TIME_UNIT_KEYS, "time_unit", source),
        columns=_check_columns(columns, source),
        number_samples=bool(number_samples),
    )
    acc_unit = check_unit_arg(acc_unit, ACC_UNIT_KEYS, "acc_unit", source)
    gyro_unit = check_unit_arg(gyro_unit, GYRO_UNIT_KEYS, "gyro_unit", source)
    select = check_select(select, source)
    if acc_only and select.get("gyro") is not None:
        raise ImucalError(f"--acc-only calibrates the accelerometer alone, but --gyro "
                          f"{select['gyro']} names a gyroscope; give one or the other",
                          source=source, field="--gyro")
    log = log_format(paths[0]) if len(paths) == 1 else None
    if log is None and select.get("gyro") is not None and gyro_path is None:
        # --gyro beside a table names the gyroscope's file (one that is not there: said below)
        paths.append(Path(select.pop("gyro")))
        source = " + ".join(display_name(p) for p in paths)
    if log is None and select.get("acc") is not None:
        raise ImucalError(f"--acc {select['acc']} names a stream of a log (a ROS bag, a ULog, "
                          "a DataFlash log); this file is a table: map its columns with "
                          "--columns", source=source, field="--acc")
    for p in paths:
        check_file(p, log is not None, MAX_FILE_BYTES)
    check_gyro_file(paths, acc_only)

    store = Spill(spill if spill is not None else SpillPolicy(), source)
    threads = usable_threads() if threads is None else max(1, int(threads))
    # A log's reader hashes the bytes it reads (ULog, DataFlash, ROS bags): the file is then
    # hashed here only where the reader did not (HDF5), on asking, not in a thread beside it.
    sha256 = _sha256_soon(paths, threads if log is None else 1)
    chosen = None
    if log is not None:
        chosen = choose_streams(paths[0], log, source, select, acc_only, opts)
        parts = parts_of(chosen)
    else:
        parts = _read_parts(paths, acc_only, opts, source, store, threads)

    acc, t_acc = settle_time(parts["acc"], opts, store.empty)
    gyro = t_gyro = None
    if "gyro" in parts:
        gyro, t_gyro = settle_time(parts["gyro"], opts, store.empty)
    if len(paths) == 2 and t_gyro is not None and opts.rate is not None:
        # Two files timed by one rate: their lengths must agree (stages/sanity.py).
        note = one_rate_pairing(t_acc, t_gyro, opts.rate, *(display_name(p) for p in paths))
        opts.notes.extend([note] if note else [])

    acc, acc_unit, gyro, final_gyro_unit = _units(acc, gyro, parts, acc_unit, gyro_unit, opts,
                                                  store)
    extras = tuple(_extra_streams(opts))

    return Session(
        acc=contiguous(acc, store),
        t_acc=contiguous(t_acc, store),
        gyro=None if gyro is None else contiguous(gyro, store),
        t_gyro=None if t_gyro is None else contiguous(t_gyro, store),
        acc_unit=acc_unit,
        gyro_unit=final_gyro_unit,
        source=source,
        sha256=(chosen.sha256 if chosen is not None and chosen.sha256 else sha256()),
        notes=tuple(dict.fromkeys(opts.notes)),  # a shared time column speaks once
        init_still_s=opts.init_still_s,
        storage=store.note(),
        chosen=() if chosen is None else tuple(
            describe(x) for x in (chosen.acc, chosen.gyro) if x is not None),
        others=_named_mag_first(extras if chosen is None else chosen.others,
                                select.get("mag"), source),
    )


def _named_mag_first(others: tuple[Stream, ...], selector: str | None, source: str
                     ) -> tuple[Stream, ...]:
    """The other streams with the magnetometer ``--mag`` names first: the pipeline calibrates
    the first magnetometer of a session (stages/mag.py)."""
    if selector is None:
        return others
    named = find(StreamSet(source, "", others), "mag", selector)
    return (named, *(s for s in others if s is not named))


def _extra_streams(opts: LoadOptions) -> list[Stream]:
    """The table's other streams (a2x…, g2x…, mx…, temp) on their own timestamps: the rows
    where they hold values (a slower magnetometer leaves the rest empty), timed as the pair is.
    One that cannot be timed is said and left out: it never stops the calibration."""
    out = []
    for kind, part in opts.extras:
        label = LABELS[part.sensor]
        finite = np.isfinite(part.values).all(axis=1)
        if part.time is not None:
            finite &= np.isfinite(part.time)
            part.time = part.time[finite]
        part.values = part.values[finite]
        scratch = LoadOptions(rate=opts.rate, time_unit=opts.time_unit, columns=None)
        try:
            values, t = settle_time(part, scratch)
        except ImucalError as e:
            opts.notes.append(f"{label} columns left out: {e.problem}")
            continue
        # a column named temp holds deg C (the naming rule says so)
        unit = "degC" if kind == "temp" else part.unit_hint
        unit = unit if unit in UNITS[kind] else None
        roles = "temp" if kind == "temp" else f"{part.sensor}x, {part.sensor}y, {part.sensor}z"
        out.append(Stream(kind, part.sensor, np.ascontiguousarray(t, dtype=float),
                          np.ascontiguousarray(values, dtype=float), unit,
                          f"{part.source}: columns {roles}", time_source="the table's time"))
        # a magnetometer is calibrated over the whole session (stages/mag.py), the rest kept
        mag = ("imucal calibrate fits it on its own clock (the magnetometer's section)",)
        opts.notes.append(beside_note(label, roles, len(t), *(mag if kind == "mag" else ())))
    return out


def _read_parts(paths: list[Path], acc_only: bool, opts: LoadOptions,
                source: str, store: Spill, threads: int) -> dict:
    """The accelerometer's and gyroscope's columns, from one file or from two."""
    if len(paths) == 2:
        first = read_file(paths[0], store, threads)
        _no_gyro_of_its_own(first, paths)
        parts = _extract(first, ("acc",), opts)
        parts.update(_extract(read_file(paths[1], store, threads), ("gyro",), opts))
        return parts
    parts = _extract(read_file(paths[0], store, threads), ("acc", "gyro"), opts)
    if "gyro" not in parts and not acc_only:
        raise ImucalError("found an accelerometer and no gyroscope; give the gyroscope's "
                          "file with --gyro FILE, or --acc-only to calibrate the "
                          "accelerometer alone", source=source, field="columns")
    if acc_only:
        parts.pop("gyro", None)
        opts.notes.append(f"accelerometer only (--acc-only): {display_name(paths[0])}")
    if "gyro" in parts:
        _share_equal_time(parts["acc"], parts["gyro"])
        own_rows(parts["acc"], parts["gyro"], opts)
    return parts


def _units(acc: np.ndarray, gyro: np.ndarray | None, parts: dict, acc_unit: str,
           gyro_unit: str, opts: LoadOptions, store: Spill
           ) -> tuple[np.ndarray, str, np.ndarray | None, str | None]:
    """Each signal in its resolved unit (named in the file, given, or guessed from the
    values), the gyroscope in rad/s unless it is raw counts; each choice in ``opts.notes``."""
    acc = _scale_named_unit(acc, parts["acc"], opts.notes, store)
    if gyro is not None:
        gyro = _scale_named_unit(gyro, parts["gyro"], opts.notes, store)
    acc_unit = resolve_acc_unit(acc, acc_unit, parts["acc"].unit_hint, parts["acc"].source,
                                opts.notes)
    if gyro is None:
        return acc, acc_unit, None, None
    gyro_unit = resolve_gyro_unit(gyro, gyro_unit, parts["gyro"].unit_hint, acc_unit,
                                  opts.notes)
    if gyro_unit == "deg/s":
        gyro = elementwise(np.deg2rad, gyro, store.empty)
        opts.notes.append(DEG_S_NOTE)
        gyro_unit = "rad/s"
    return acc, acc_unit, gyro, gyro_unit


# --- argument checks -----------------------------------------------------------------------------


def _check_rate(rate: float | None, source: str) -> float | None:
    if rate is None:
        return None
    try:
        value = float(rate)
    except (TypeError, ValueError):
        raise ImucalError(f"sample rate must be a number of Hz, got {rate!r}",
                          source=source, field="rate") from None
    if not math.isfinite(value) or not MIN_RATE_HZ <= value <= MAX_RATE_HZ:
        raise ImucalError(
            f"sample rate must be a number of Hz from {MIN_RATE_HZ:.4g} (one sample a minute) to "
            f"{MAX_RATE_HZ:g}, got {rate!r}", source=source, field="rate",
        )
    return value


def _check_columns(columns: Mapping[str, str | int] | None, source: str) -> dict | None:
    if columns is None:
        return None
    if not isinstance(columns, Mapping):
        raise ImucalError("expected a mapping of role to column name, e.g. {'ax': 'acc_x'}",
                          source=source, field="columns")
    unknown = [k for k in columns if k not in ALL_ROLES]
    if unknown:
        raise ImucalError(f"unknown role(s) {', '.join(map(repr, unknown))}; expected keys from "
                          f"{', '.join(ALL_ROLES)}", source=source, field="columns")
    for role, col in columns.items():
        ok = isinstance(col, str) or (isinstance(col, int) and not isinstance(col, bool))
        if not ok or (isinstance(col, int) and col < 0):
            raise ImucalError(f"{role!r} must map to a column name or a 0-based position, "
                              f"got {col!r}", source=source, field="columns")
    return dict(columns)


def _no_gyro_of_its_own(content: Table | Variables, paths: list[Path]) -> None:
    """A session file with a gyroscope of its own and a --gyro file beside it: which one is
    meant cannot be told; refused rather than one silently dropped (issue 27). Found by the
    names alone (--columns maps the accelerometer file's columns, not these)."""
    if isinstance(content, Table) and content.names is None:
        return  # no header: one file of a pair must have 3 columns (said by from_positions)
    scratch = LoadOptions(rate=1.0, time_unit="s", columns=None)
    try:
        own = "gyro" in _extract(content, ("acc", "gyro"), scratch)
    except ImucalError:
        own = False
    if own:
        raise ImucalError(f"has a gyroscope of its own, and --gyro {display_name(paths[1])} "
                          "names another; drop --gyro to use the file's own, or give a file "
                          "with the accelerometer alone", source=display_name(paths[0]),
                          field="--gyro")


def _sha256_soon(paths: list[Path], threads: int) -> Callable[[], str]:
    """The files' SHA-256: hashed in a thread of its own while they load, when more than one
    thread is allowed (hashlib releases the GIL; 1 GB at 6 hours is a second), else on asking."""
    if threads <= 1:
        return lambda: _sha256(paths)
    pool = ThreadPoolExecutor(1, thread_name_prefix="imucal-sha256")
    future = pool.submit(_sha256, paths)
    pool.shutdown(wait=False)  # a load that fails does not wait for the hash
    return future.result


def _sha256(paths: list[Path]) -> str:
    digest = hashlib.sha256()
    # A ROS 2 bag is a folder: its files in name order.
    files = [f for p in paths for f in (sorted(x for x in p.rglob("*") if x.is_file())
                                        if p.is_dir() else [p])]
    for p in files:
        with p.open("rb") as fh:
            while chunk := fh.read(_CHUNK):
                digest.update(chunk)
    return digest.hexdigest()


def _share_equal_time(acc: Part, gyro: Part, rows: int = 1 << 16) -> None:
    """One time array for both sensors when their time variables hold the same values (a .mat
    with t_acc and t_gyro, as imucal synth writes): the session then holds one copy, 170 MB
    less at 6 hours of 1 kHz. Compared a block at a time, with no signal-sized temporary."""
    a, b = acc.time, gyro.time
    if (a is None or b is None or a is b or a.shape != b.shape or a.dtype != np.float64
            or b.dtype != np.float64):
        return
    for lo in range(0, len(a), rows):  # bit for bit: 0.0 and -0.0 are not the same time
        if not np.array_equal(a[lo:lo + rows].view(np.int64), b[lo:lo + rows].view(np.int64)):
            return
    gyro.time = a


def _scale_named_unit(values: np.ndarray, part: Part, notes: list[str], store: Spill
                      ) -> np.ndarray:
    """Values in a unit only a column name uses (mg, mdeg/s) in the unit it scales."""
    if part.unit_hint not in SCALED_UNITS:
        return values
    unit, scale = SCALED_UNITS[part.unit_hint]
    notes.append(f"{LABELS[part.sensor]} converted from {part.unit_hint} to {unit}, as the "
                 "column names say")
    part.unit_hint = unit
    return elementwise(lambda x, out: np.multiply(x, scale, out=out), values, store.empty)


def _extract(content: Table | Variables, sensors: tuple[str, ...],
             opts: LoadOptions) -> dict[str, Part]:
    if isinstance(content, Variables):
        return from_variables(content, sensors, opts)
    opts.notes.extend(content.notes)
    if content.names is None:
        parts = from_positions(content, sensors, opts)
    else:
        parts = from_names(content, sensors, opts)
    if content.preamble:
        _take_facts(read_facts(content.preamble), content.source, parts, opts)
    return parts


def _take_facts(facts: FileFacts, source: str, parts: dict[str, Part],
                opts: LoadOptions) -> None:
    """Hand what a file's preamble states to its parts (a rate, a time unit) and to the
    session (an initial still period), and say what was read."""
    said = facts.summary()
    if said:
        opts.notes.append(f"{source}: its preamble states {said}")
    for part in parts.values():
        part.stated_rate = facts.rate_for(part.sensor)
        if facts.time_unit is not None and part.time_unit is None:
            part.time_unit = facts.time_unit[0]
            part.time_unit_from = f"as the file states ({facts.time_unit[1]})"
    if facts.init_still_s is not None and opts.init_still_s is None:
        opts.init_still_s = facts.init_still_s[0]
