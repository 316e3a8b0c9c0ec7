"""A calibration store per device: a folder of calib.json files (the source of truth) and a
Parquet index rebuilt from it.

::

    STORE/
      DEVICE/2024-05-01T093000Z.calib.json     a calibration of DEVICE made at that time (UTC)
      DEVICE/2024-05-01T093000Z-2.calib.json   another one of the same second, added after it
      DEVICE/.lock                              held while a calibration is added to DEVICE
      index.parquet                             one row per file: derived, rebuilt when missing
                                                or stale (delete it at will)
      .index.lock                               held while the index is rewritten

The path says whose calibration a file is and when it was made (``calibrated_at``: when the
unit was calibrated, i.e. when its calibration session was recorded, to the second); a file is
the calib.json as ``imucal calibrate`` or ``imucal batch`` wrote it, plus a ``store`` block
saying where that time came from. Files can be added, removed or renamed by hand (or by git):
the index follows the folder.

Two processes adding at once never clobber each other: an add holds its device folder's lock
(``fcntl.flock``, which Linux also honours on NFS) while it picks a free name and writes the
file (atomically: :func:`imucal.io.atomic.write_text_atomic`), and the index is rewritten under
its own lock from what is on disk, so the last writer's index has every file.
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

from imucal.errors import ImucalError, plural
from imucal.fleet import naming
from imucal.fleet.index import (
    DEVICE_LOCK,
    NAME,
    STAMP,
    SUFFIX,
    content_key,
    file_name,
    iso,
    locked,
    read_calibration,
    refresh_index,
)

DEFAULT_MAX_AGE = "90d"
_AGE = re.compile(r"^\s*(\d+(?:\.\d*)?)\s*([smhdw])\s*$")
_AGE_UNITS = {"s": 1, "m": 60, "h": 3600, "d": 86400, "w": 7 * 86400}


@dataclass(frozen=True)
class Added:
    device: str
    path: Path
    calibrated_at: datetime
    when_from: str
    already: bool  # the same calibration (inputs, settings, results) was there: nothing written


@dataclass(frozen=True)
class Picked:
    """The calibration in force for a device at a time, and how old it was then."""

    row: dict[str, Any]
    path: Path
    at: datetime
    max_age: timedelta | None

    @property
    def age(self) -> timedelta:
        return self.at - self.row["calibrated_at"]

    @property
    def too_old(self) -> bool:
        return self.max_age is not None and self.age > self.max_age


# --- names, times, ages --------------------------------------------------------------------------


def device_id(text: str | None, source: str = "--device") -> str:
    """A device id as given, refused when it cannot name one folder."""
    name = (text or "").strip()
    if not name or naming.safe_name(name) != name:
        raise ImucalError(f"{text!r} is not a usable device id (it names a folder: letters, "
                          "digits and . _ + - only)", source=source)
    return name


def parse_when(text: str, source: str) -> datetime:
    """A time from the command line ('2024-05-01', '2024-05-01T12:30:00Z', ...), UTC."""
    try:
        return naming.parse_time(text, source=source)
    except ImucalError as e:
        raise ImucalError(f"cannot read {text!r} as a time (expected e.g. 2024-05-01 or "
                          "2024-05-01T12:30:00Z)", source=source) from e


def parse_age(text: str, source: str = "--max-age") -> timedelta:
    """'90d', '12h', '2w', '30m', '45s' -> a positive timedelta."""
    m = _AGE.match(text or "")
    if m is None or float(m.group(1)) <= 0:
        raise ImucalError(f"cannot read {text!r} as an age (expected a positive number and a "
                          "unit s, m, h, d or w, e.g. 90d)", source=source)
    return timedelta(seconds=float(m.group(1)) * _AGE_UNITS[m.group(2)])


def describe_age(age: timedelta) -> str:
    days = age.total_seconds() / 86400
    return f"{days:.0f} days" if abs(days) >= 2 else f"{age.total_seconds() / 3600:.1f} hours"


def _second(t: datetime) -> datetime:
    """UTC to the second (the resolution of a stored file's name); a naive time is UTC."""
    t = t if t.tzinfo is not None else t.replace(tzinfo=timezone.utc)
    return t.astimezone(timezone.utc).replace(microsecond=0)


# --- adding --------------------------------------------------------------------------------------


def _when(doc: dict[str, Any], path: Path, when: datetime | None) -> tuple[datetime, str]:
    """When the calibration was made: --when, else the time its session was recorded (imucal
    batch writes it), else when the batch ran, else the file's modification time."""
    if when is not None:
        return when, "--when"
    for key in ("recorded_at", "calibrated_at"):
        text = doc.get(key)
        if isinstance(text, str) and text:
            try:
                return naming.parse_time(text, source=str(path)), key
            except ImucalError:
                raise ImucalError(f"{text!r} is not a time", source=str(path),
                                  field=key) from None
    return datetime.fromtimestamp(path.stat().st_mtime, tz=timezone.utc), "file mtime"



def device_folder(root: Path, dev: str) -> Path:
    """The device's folder in the store, made if new (a failure is one line naming it)."""
    folder = root / dev
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ImucalError(f"cannot create the device folder ({e.strerror or e})",
                          source=str(folder)) from None
    return folder

def add(store: str | os.PathLike, calib: str | os.PathLike, device: str | None = None,
        when: datetime | None = None, *, update_index: bool = True) -> Added:
    """Store a copy of ``calib`` under ``STORE/DEVICE/`` named by its time. The device defaults
    to the file's own ``device`` (imucal batch writes it). A calibration already stored for
    that device at that second is not stored twice."""
    root, calib = Path(store), Path(calib)
    if root.exists() and not root.is_dir():
        raise ImucalError("is a file; expected the store's folder", source=str(root))
    doc, _ = read_calibration(calib)
    if device is None and not isinstance(doc.get("device"), str):
        raise ImucalError("no device id in the file; give --device", source=str(calib),
                          field="device")
    dev = device_id(device if device is not None else doc["device"],
                    "--device" if device is not None else str(calib))
    at, how = _when(doc, calib, when)
    at = _second(at)
    key = content_key(doc)
    folder = device_folder(root, dev)
    stamp = at.strftime(STAMP)
    with locked(folder / DEVICE_LOCK):
        _same_unit(folder, dev, doc, device, calib)
        same_second = {}
        for p in folder.glob(f"{stamp}*{SUFFIX}"):
            m = NAME.match(p.name)
            if m is not None and m.group(1) == stamp:
                same_second[int(m.group(2) or 1)] = p
        for seq in sorted(same_second):
            if _stored_key(same_second[seq]) == key:
                return Added(dev, same_second[seq], at, how, already=True)
        target = folder / file_name(at, max(same_second, default=0) + 1)
        block = {"device": dev, "calibrated_at": iso(at), "when_from": how,
                 "added_from": str(calib.resolve()), "added_at": iso(datetime.now(timezone.utc))}
        stored = {k: v for k, v in doc.items() if k != "store"} | {"store": block}
        from imucal.io.atomic import write_text_atomic

        write_text_atomic(target, json.dumps(stored, indent=2, allow_nan=False) + "\n")
    if update_index:
        refresh_index(root)
    return Added(dev, target, at, how, already=False)


NAMED = ".named"  # in a device folder: the text its id was made from (a folder's name)


def _same_unit(folder: Path, dev: str, doc: dict, device: str | None, calib: Path) -> None:
    """Two units never share one history (issue 27): a batch made ``dev`` from a folder's name
    (``device_named``, e.g. "IMU 1"); a calibration of a unit whose id was made from another
    text ("IMU_1") is refused. The first one to come names the folder (``.named``); a
    calibration relabelled by an explicit --device is the user's call."""
    named = doc.get("device_named")
    if not isinstance(named, str) or (device is not None and device != doc.get("device")):
        return
    mark = folder / NAMED
    try:
        there = mark.read_text(encoding="utf-8")
    except FileNotFoundError:
        from imucal.io.atomic import write_text_atomic

        write_text_atomic(mark, named)
        return
    if there != named:
        raise ImucalError(f"device {dev!r} of the store holds calibrations of {there!r}, this "
                          f"file is of {named!r}: two units would be merged; give --device to "
                          "store it under an id of its own", source=str(calib), field="device")


def _stored_key(path: Path) -> str | None:
    try:
        return content_key(json.loads(path.read_text(encoding="utf-8")))
    except (OSError, ValueError, AttributeError):
        return None


# --- reading -------------------------------------------------------------------------------------


def calibrations(store: str | os.PathLike, device: str | None = None) -> list[dict[str, Any]]:
    """The usable calibrations (oldest first), of one device or all; an unknown device is an
    error naming the ones there are."""
    frame = refresh_index(store)
    rows = [r for r in frame.to_dicts() if r["error"] is None]
    if device is not None:
        rows = [r for r in rows if r["device"] == device]
        if not rows:
            there = sorted({r["device"] for r in frame.to_dicts() if r["error"] is None})
            raise ImucalError(f"no calibrations of device {device!r} in the store (it has "
                              f"{plural(len(there), 'device')}: {', '.join(there) or 'none'})",
                              source=str(store), field="--device")
    return rows


def problems(store: str | os.PathLike) -> list[str]:
    """Files of the store the index leaves out, each with why."""
    return [r["error"] for r in refresh_index(store).to_dicts() if r["error"] is not None]


def newest(rows: list[dict[str, Any]], at: datetime) -> dict[str, Any] | None:
    """The newest of ``rows`` made at or before ``at`` (the later added of one second)."""
    before = [r for r in rows if r["calibrated_at"] <= at]
    return max(before, key=lambda r: (r["calibrated_at"], r["seq"])) if before else None


def get(store: str | os.PathLike, device: str, at: datetime | None = None,
        max_age: timedelta | None = None) -> Picked:
    """The calibration of ``device`` in force at ``at`` (now by default)."""
    rows = calibrations(store, device)
    at = at or datetime.now(timezone.utc)
    row = newest(rows, at)
    if row is None:
        raise ImucalError(f"no calibration of {device} at or before {iso(at)} (its oldest is "
                          f"of {iso(rows[0]['calibrated_at'])})", source=str(store),
                          field="--at")
    return Picked(row=row, path=Path(store) / row["path"], at=at, max_age=max_age)


def format_table(header: list[str], rows: list[list[str]], right: set[int] = frozenset()
                 ) -> list[str]:
    """Aligned text columns (``right``: the indices of right-aligned ones)."""
    widths = [max(len(x) for x in col) for col in zip(header, *rows)]
    return ["  ".join(c.rjust(w) if i in right else c.ljust(w)
                      for i, (c, w) in enumerate(zip(line, widths))).rstrip()
            for line in [header, *rows]]


def list_lines(rows: list[dict[str, Any]], now: datetime | None = None) -> list[str]:
    """The store's listing: one line per calibration."""
    now = now or datetime.now(timezone.utc)

    def fmt(x: float | None) -> str:
        return "-" if x is None else f"{x:.3g}"

    body = [[r["device"], iso(r["calibrated_at"]), r["when_from"] or "-",
             describe_age(now - r["calibrated_at"]), fmt(r["static_norm_rms_mg_after"]),
             {True: "pass", False: "FAIL", None: "-"}[r["spec_pass"]], r["path"]]
            for r in rows]
    return format_table(["device", "calibrated_at", "from", "age", "static_mg", "spec", "file"],
                        body, right={3, 4})


__all__ = ["Added", "DEFAULT_MAX_AGE", "Picked", "add", "calibrations", "describe_age",
           "device_id", "format_table", "get", "list_lines", "newest", "parse_age", "parse_when",
           "problems"]
