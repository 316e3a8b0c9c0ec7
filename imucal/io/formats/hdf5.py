"""HDF5 files (and MATLAB v7.3 files, which are HDF5 inside) holding one dataset per sensor,
read with h5py: ``imu_acc``/``imu_gyr``/``imu_mag`` (the BROAD benchmark), ``accelBuffer``,
``/imu0/gyro``, ``temperature``.

A dataset's sensor is read from its name (the last part of its path, split at ``_``, ``.`` and
camelCase: ``imu_acc`` -> imu, acc); datasets that name no sensor (``opt_quat``, ``movement``)
are left alone. A dataset's samples run along its longer side; a fourth column (or row) before
the three axes is its time. Otherwise its time is a sibling dataset named ``t``/``time`` of the
same length, or a ``sampling_rate`` attribute (of the dataset, its group or the file). A file in
the layout the table loader knows (variables ``acc``/``gyro``, or one matrix) never comes here
(:func:`is_stream_file`), so its results do not change.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from imucal.errors import ImucalError
from imucal.streams import Stream, StreamSet

_KIND_WORDS = {
    "acc": ("acc", "accel", "accl", "accelerometer", "acceleration", "accelerations"),
    "gyro": ("gyr", "gyro", "gyroscope", "angvel", "omega"),
    "mag": ("mag", "magn", "magnetometer", "compass", "magnetic"),
    "temp": ("temp", "temperature"),
}
_TIME_NAMES = ("t", "time", "times", "timestamp", "timestamps")
_RATE_ATTRS = ("sampling_rate", "sample_rate", "rate", "fs", "frequency")
_UNIT_ATTRS = ("unit", "units")
_UNITS = {"acc": {"g": "g", "m/s^2": "m/s^2", "m/s2": "m/s^2", "m/s²": "m/s^2"},
          "gyro": {"rad/s": "rad/s", "deg/s": "deg/s", "dps": "deg/s"},
          "mag": {"ut": "uT", "µt": "uT", "gauss": "gauss", "mg": "mG", "t": "T"},
          "temp": {"degc": "degC", "c": "degC", "°c": "degC"}}
# Variable names the table loader takes (imucal.io.mat_layout): such a file stays on that path.
_LEGACY = ("acc", "accel", "acceleration", "accelerometer", "a", "acc_data", "gyro", "gyr",
           "gyroscope", "w", "omega", "gyro_data")


def _words(name: str) -> list[str]:
    spaced = re.sub(r"([a-z0-9])([A-Z])", r"\1 \2", name)
    return [w.lower() for w in re.split(r"[^A-Za-z0-9]+", spaced) if w]


def _kind(name: str) -> str | None:
    words = _words(name)
    for kind, names in _KIND_WORDS.items():
        if any(w in names for w in words):
            return kind
    return None


def _datasets(f) -> dict[str, object]:
    """Every numeric dataset by path (MATLAB's own bookkeeping, ``#refs#``, left out)."""
    import h5py

    found: dict[str, object] = {}

    def visit(name: str, item: object) -> None:
        if (isinstance(item, h5py.Dataset) and not name.startswith("#")
                and item.dtype.kind in "iufb" and item.ndim in (1, 2) and item.size > 0):
            found[name] = item

    f.visititems(visit)
    return found


def is_stream_file(path: Path) -> bool:
    """Datasets that name sensors, and not in the layout the table loader already reads."""
    import h5py

    with h5py.File(path, "r") as f:
        sets = _datasets(f)
        top = {n.lower() for n in sets if "/" not in n}
        if top & set(_LEGACY):
            return False
        kinds = {n: _kind(n.rsplit("/", 1)[-1]) for n in sets}
        named = {n: k for n, k in kinds.items() if k is not None}
        matrices = [n for n, d in sets.items() if min(d.shape + (9,)) > 1 and d.ndim == 2]
        if len(matrices) <= 1:
            # One matrix: the thesis's layout (any name), unless its name says which one sensor
            # it holds and its shape fits that sensor (compassBuffer: 4 x N, time then x y z).
            return bool(named) and all(
                min(sets[n].shape) in ((1, 2) if k == "temp" else (3, 4))
                for n, k in named.items())
        return any(k in ("acc", "gyro") for k in named.values())


def read_streams(path: Path, source: str, keep, key: str = "hdf5") -> StreamSet:
    import h5py

    streams: list[Stream] = []
    notes: list[str] = []
    with h5py.File(path, "r") as f:
        sets = _datasets(f)
        for name, item in sets.items():
            leaf = name.rsplit("/", 1)[-1]
            kind = _kind(leaf)
            if kind is None or (keep is not None and not keep(name)):
                continue
            made = _stream(f, name, item, kind, sets, source)
            if isinstance(made, str):
                notes.append(made)
            else:
                streams.append(made)
    if not streams:
        named = ", ".join(sorted(sets)) or "no numeric datasets"
        raise ImucalError(f"no sensor dataset found ({named}); name them like acc, gyro, "
                          "imu_acc, accelBuffer, compassBuffer, temperature", source=source,
                          field="datasets")
    return StreamSet(source, "HDF5", tuple(streams), notes=tuple(notes))


def _stream(f, name: str, item, kind: str, sets: dict, source: str) -> Stream | str:
    width = 1 if kind == "temp" else 3
    arr = np.asarray(item[()], dtype=np.float64)
    if arr.ndim == 1:
        arr = arr[:, None]
    if item.attrs.get("MATLAB_class") is not None:
        arr = arr.T  # MATLAB writes column-major: h5py sees its matrices transposed
    if arr.shape[1] not in (width, width + 1) and arr.shape[0] in (width, width + 1):
        arr = arr.T  # samples along the longer side
    if arr.shape[1] not in (width, width + 1) or len(arr) < 2:
        return f"dataset {name!r} ({item.shape}) left out: expected {width} axes per sample"
    parent = name.rsplit("/", 1)[0] if "/" in name else ""
    if arr.shape[1] == width + 1:
        t, values, how = arr[:, 0], arr[:, 1:], f"its first {'column' if width else 'row'}"
    else:
        values = arr
        t, how = _sibling_time(sets, parent, len(arr))
        if t is None:
            rate = _rate(f, item, parent)
            if rate is None:
                return (f"dataset {name!r} left out: no time column, no t/time dataset of "
                        f"{len(arr)} values beside it and no sampling_rate attribute")
            t, how = np.arange(len(arr)) / rate, f"sampling_rate attribute ({rate:g} Hz)"
    unit, said = _unit(f, item, name, kind)
    stem = [w for w in _words(name.rsplit("/", 1)[-1]) if w not in _KIND_WORDS[kind]]
    imu = "/".join(filter(None, [parent, "_".join(stem)])) or None
    notes = (f"{name}: unit {unit} as {said} states",) if unit else ()
    return Stream(kind, name, np.ascontiguousarray(t), np.ascontiguousarray(values), unit,
                  f"{source}: dataset {name!r}", time_source=how, imu=imu, notes=notes)


def _sibling_time(sets: dict, parent: str, n: int) -> tuple[np.ndarray | None, str]:
    for tn in _TIME_NAMES:
        path = f"{parent}/{tn}" if parent else tn
        item = sets.get(path)
        if item is not None and item.size == n:
            return np.asarray(item[()], dtype=np.float64).ravel(), f"dataset {path!r}"
    return None, ""


def _rate(f, item, parent: str) -> float | None:
    for holder in (item, f[parent] if parent else f, f):
        for a in _RATE_ATTRS:
            if a in holder.attrs:
                try:
                    rate = float(np.asarray(holder.attrs[a]).ravel()[0])
                except (TypeError, ValueError, IndexError):
                    continue
                if np.isfinite(rate) and rate > 0:
                    return rate
    return None


def _unit(f, item, name: str, kind: str) -> tuple[str | None, str]:
    """The unit a ``unit``/``units`` attribute states, else the one the file's description
    states for this dataset ("`imu_gyr` in rad/s", as BROAD's ``info`` says), and where."""
    for a in _UNIT_ATTRS:
        if a in item.attrs:
            return _UNITS[kind].get(_text(item.attrs[a]).replace(" ", "").lower()), f"{a!r}"
    leaf = re.escape(name.rsplit("/", 1)[-1])
    for a, v in f.attrs.items():
        m = re.search(rf"`?\b{leaf}\b`?\s+in\s+([^\s,;)]+)", _text(v))
        if m:
            unit = _UNITS[kind].get(m.group(1).rstrip(".").lower())
            if unit is not None:
                return unit, f"the file's {a!r} attribute"
    return None, ""


def _text(v: object) -> str:
    return v.decode(errors="replace") if isinstance(v, bytes) else str(v)
