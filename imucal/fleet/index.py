"""The calibration store's layout and its index: one row per stored calib.json, read from the
folder (the source of truth) and kept in ``STORE/index.parquet``.

The index is derived: it is rebuilt when missing, unreadable or stale, where stale means that
the set of files, or the size or modification time of one, differs from what it recorded.
Only new or changed files are read again; removed ones drop out. See
:mod:`imucal.fleet.store` for the layout and the commands.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
from collections.abc import Iterator
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from imucal.errors import ImucalError
from imucal.fleet import naming
from imucal.fleet.summary import GYRO_BIAS_NAMES
from imucal.models import ACC_PARAM_NAMES, GYRO_PARAM_NAMES

INDEX = "index.parquet"
INDEX_LOCK = ".index.lock"
DEVICE_LOCK = ".lock"
SUFFIX = ".calib.json"
STAMP = "%Y-%m-%dT%H%M%SZ"
NAME = re.compile(r"^(\d{4}-\d{2}-\d{2}T\d{6}Z)(?:-([1-9][0-9]*))?\.calib\.json$")

# The index's columns (name -> kind); the parameters are named as in summary.parquet.
GYRO_NAMES = GYRO_PARAM_NAMES + GYRO_BIAS_NAMES
_COLUMNS: dict[str, str] = {
    "device": "str", "calibrated_at": "datetime", "seq": "int", "path": "str",
    "when_from": "str", "added_at": "datetime", "added_from": "str", "source_file": "str",
    "source_sha256": "str", "content_key": "str", "acc_unit_raw": "str", "gyro_unit_raw": "str",
    "segments": "int",
    **{f"acc_{n}": "float" for n in ACC_PARAM_NAMES},
    **{f"acc_std_{n}": "float" for n in ACC_PARAM_NAMES},
    **{f"gyro_{n}": "float" for n in GYRO_NAMES},
    **{f"gyro_std_{n}": "float" for n in GYRO_NAMES},
    "static_norm_rms_mg_after": "float", "static_norm_rms_mg_cv": "float",
    "gravity_angle_rms_deg_after": "float", "gravity_angle_rms_deg_cv": "float",
    "spec_pass": "bool", "error": "str", "file_size": "int", "file_mtime_ns": "int",
}
INDEX_COLUMNS = tuple(_COLUMNS)


def iso(t: datetime) -> str:
    return t.astimezone(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def file_name(at: datetime, seq: int) -> str:
    """``2024-05-01T093000Z.calib.json``, ``...Z-2.calib.json`` for the second of a second."""
    return f"{at.strftime(STAMP)}{'' if seq == 1 else f'-{seq}'}{SUFFIX}"


@contextlib.contextmanager
def locked(path: Path) -> Iterator[None]:
    """An exclusive lock on ``path`` (created if missing), released when the block ends."""
    import fcntl

    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)  # waits for the holder: writers take turns
        yield
    finally:
        os.close(fd)  # closing the descriptor releases the lock


def content_key(doc: dict[str, Any]) -> str:
    """What makes two calib.json files the same calibration: its input, settings, units and
    parameters (not when or where it was written)."""
    keep = {k: doc.get(k) for k in ("source", "settings", "units", "segments")}
    return hashlib.sha256(json.dumps(keep, sort_keys=True).encode()).hexdigest()[:16]


def read_calibration(path: Path) -> tuple[dict[str, Any], Any]:
    """The file's JSON and its :class:`~imucal.stages.apply.Calibration` (the checks of
    ``imucal apply``: a file that could not be applied is refused)."""
    from imucal.io.calibration_file import load_calibration

    calibration = load_calibration(path)
    return json.loads(path.read_text(encoding="utf-8")), calibration


# --- one row per file ----------------------------------------------------------------------------


def _scan(root: Path) -> dict[str, tuple[int, int]]:
    """Every calib.json of the store: relative path -> (size, mtime in ns)."""
    found: dict[str, tuple[int, int]] = {}
    with os.scandir(root) as top:
        entries = [e for e in top if not e.name.startswith(".")]
    for entry in entries:
        if entry.is_file() and entry.name.endswith(SUFFIX):
            st = entry.stat()
            found[entry.name] = (st.st_size, st.st_mtime_ns)
        elif entry.is_dir():
            with os.scandir(entry.path) as inner:
                for f in inner:
                    if f.name.endswith(SUFFIX) and not f.name.startswith(".") and f.is_file():
                        st = f.stat()
                        found[f"{entry.name}/{f.name}"] = (st.st_size, st.st_mtime_ns)
    return found


def _num(x: Any) -> float | None:
    return float(x) if isinstance(x, (int, float)) and not isinstance(x, bool) else None


def _entry(root: Path, rel: str, stat: tuple[int, int]) -> dict[str, Any]:
    """One index row, from the file's path and contents alone (a file that cannot be read
    is a row with its error, so that it is not read again until it changes)."""
    row: dict[str, Any] = dict.fromkeys(_COLUMNS)
    row |= {"path": rel, "file_size": stat[0], "file_mtime_ns": stat[1]}
    parts = rel.split("/")
    m = NAME.match(parts[-1])
    row["device"] = parts[0] if len(parts) == 2 else None
    if len(parts) != 2 or m is None:
        row["error"] = f"{rel}: not named DEVICE/YYYY-MM-DDTHHMMSSZ{SUFFIX}; left out"
        return row
    row["calibrated_at"] = datetime.strptime(m.group(1), STAMP).replace(tzinfo=timezone.utc)
    row["seq"] = int(m.group(2) or 1)
    try:
        doc, cal = read_calibration(root / rel)
        row |= _provenance(doc, row) | _parameters(doc, cal)
    except ImucalError as e:
        row["error"] = str(e)
    except OSError as e:
        row["error"] = f"{rel}: {e.strerror or e}"
    return row


def _provenance(doc: dict[str, Any], row: dict[str, Any]) -> dict[str, Any]:
    block = doc.get("store") if isinstance(doc.get("store"), dict) else {}
    # The path is the truth: a file renamed or moved by hand is what its name says.
    named = block.get("device") == row["device"] and block.get("calibrated_at") == iso(
        row["calibrated_at"])
    added_at = None
    with contextlib.suppress(ImucalError, AttributeError, TypeError):
        added_at = naming.parse_time(block["added_at"]) if "added_at" in block else None
    source = doc.get("source") if isinstance(doc.get("source"), dict) else {}
    spec = doc.get("spec") if isinstance(doc.get("spec"), dict) else {}
    return {"when_from": block.get("when_from") if named else "file name",
            "added_at": added_at, "added_from": block.get("added_from"),
            "source_file": source.get("file"), "source_sha256": source.get("sha256"),
            "content_key": content_key(doc),
            "spec_pass": spec.get("pass") if isinstance(spec.get("pass"), bool) else None}


def _parameters(doc: dict[str, Any], cal: Any) -> dict[str, Any]:
    """The first segment's parameters (method.md M2, M4) in summary.parquet's names."""
    from imucal.models import acc_theta, gyro_theta

    seg, seg_doc = cal.segments[0], doc["segments"][0]
    row: dict[str, Any] = {"acc_unit_raw": cal.acc_unit_raw, "gyro_unit_raw": cal.gyro_unit_raw,
                           "segments": len(cal.segments)}
    row |= {f"acc_{n}": float(v) for n, v in zip(ACC_PARAM_NAMES, acc_theta(seg.acc))}
    std = (seg_doc.get("accelerometer") or {}).get("std") or {}
    row |= {f"acc_std_{n}": _num(std.get(n)) for n in ACC_PARAM_NAMES}
    if seg.gyro is not None:
        values = [*gyro_theta(seg.gyro), *seg.gyro.b]
        row |= {f"gyro_{n}": float(v) for n, v in zip(GYRO_NAMES, values)}
        std = (seg_doc.get("gyroscope") or {}).get("std") or {}
        row |= {f"gyro_std_{n}": _num(std.get(n)) for n in GYRO_NAMES}
    q = doc.get("quality") or {}
    static, angle = q.get("static_norm_rms_mg") or {}, q.get("gravity_angle_rms_deg") or {}
    return row | {"static_norm_rms_mg_after": _num(static.get("after")),
                  "static_norm_rms_mg_cv": _num(static.get("cross_validated")),
                  "gravity_angle_rms_deg_after": _num(angle.get("after")),
                  "gravity_angle_rms_deg_cv": _num(angle.get("cross_validated"))}


# --- the table -----------------------------------------------------------------------------------


def _to_frame(rows: list[dict[str, Any]]):
    """The rows in a fixed order (device, time, then the order of adding within a second)."""
    import polars as pl

    types = {"str": pl.String, "float": pl.Float64, "int": pl.Int64, "bool": pl.Boolean,
             "datetime": pl.Datetime("us", "UTC")}
    schema = {name: types[kind] for name, kind in _COLUMNS.items()}
    never = datetime.max.replace(tzinfo=timezone.utc)
    rows = sorted(rows, key=lambda r: (r["device"] or "", r["calibrated_at"] or never,
                                       r["seq"] or 0, r["path"]))
    return pl.DataFrame(rows, schema=schema, orient="row")


def _read_index(root: Path):
    """The index on disk, or None when missing, unreadable or of another layout."""
    import polars as pl

    path = root / INDEX
    if not path.is_file():
        return None
    try:
        frame = pl.read_parquet(path)
    except Exception:  # a damaged index is rebuilt, never trusted
        return None
    return frame if list(frame.columns) == list(INDEX_COLUMNS) else None


def _signature(frame) -> dict[str, tuple[int, int]]:
    return {p: (s, m) for p, s, m in zip(frame["path"], frame["file_size"],
                                          frame["file_mtime_ns"])}


@contextlib.contextmanager
def _index_lock(root: Path) -> Iterator[bool]:
    """The index lock; False (and no lock) where the store cannot be written (read-only)."""
    import fcntl

    try:
        fd = os.open(root / INDEX_LOCK, os.O_RDWR | os.O_CREAT, 0o666)
    except OSError:  # a read-only store is read, and its index kept in memory
        yield False
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield True
    finally:
        os.close(fd)


def refresh_index(store: str | os.PathLike, *, rebuild: bool = False):
    """The index as a polars DataFrame, brought up to date with the folder (only new or
    changed files are read; ``rebuild`` reads them all) and written back when it changed."""
    root = Path(store)
    if not root.is_dir():
        raise ImucalError("no calibration store here (the folder does not exist)",
                          source=str(root))
    old = None if rebuild else _read_index(root)
    if old is not None and _signature(old) == _scan(root):
        return old
    with _index_lock(root) as writable:
        old = None if rebuild else _read_index(root)  # another process may have just written it
        files = _scan(root)
        if old is not None and _signature(old) == files:
            return old
        known = {} if old is None else {r["path"]: r for r in old.to_dicts()}
        rows = [known[rel] if rel in known and (known[rel]["file_size"],
                                                known[rel]["file_mtime_ns"]) == stat
                else _entry(root, rel, stat) for rel, stat in files.items()]
        frame = _to_frame(rows)
        if writable:
            from imucal.io.atomic import atomic_path

            with atomic_path(root / INDEX) as tmp:
                frame.write_parquet(tmp)
    return frame


def rebuild_index(store: str | os.PathLike):
    """The index read afresh from every file of the folder (and written)."""
    return refresh_index(store, rebuild=True)
