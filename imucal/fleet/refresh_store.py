"""``imucal refresh ... --store STORE``: the refreshed calibration written to ``--out`` and added
to its device's calibration store as a new version, both or neither (one
:class:`~imucal.io.atomic.Transaction`, the store's file created, never replaced).

The new version is named by when the recording of use was made (its file's modification time,
as batch dates a session without a pattern): the calibration describes the device then. Its
``refresh`` section (written by :func:`imucal.io.inuse_file.refreshed_dict`) is the
provenance: which recording (path and SHA-256), which parameters changed, by how much, with
standard errors, and which were kept and why; the ``store`` block adds the version it was
refreshed from when that one was in the store.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from imucal.errors import ImucalError
from imucal.fleet import naming
from imucal.fleet.index import DEVICE_LOCK, NAME, STAMP, SUFFIX, file_name, iso, locked
from imucal.fleet.store import _second, _stored_key, content_key, device_folder, device_id


@dataclass(frozen=True)
class Version:
    device: str
    path: Path
    calibrated_at: datetime
    already: bool  # the same refreshed calibration was stored (at that second): not again


def device_of(doc: dict[str, Any], device: str | None, source: str) -> str:
    """--device, else the calibration's own: ``device`` (imucal batch writes it) or the
    ``store`` block of a calibration taken from a store."""
    if device is not None:
        return device_id(device)
    for text in (doc.get("device"), (doc.get("store") or {}).get("device")
                 if isinstance(doc.get("store"), dict) else None):
        if isinstance(text, str):
            return device_id(text, source)
    raise ImucalError("no device id in the calibration (neither 'device' nor 'store.device'); "
                      "give --device", source=source, field="device")


def write_with_store(out: str | os.PathLike, doc: dict[str, Any], *, store: Path,
                     device: str | None, calibration: Path, recording: Path,
                     inputs: list, rrd: str | os.PathLike | None = None,
                     write_rrd: Callable[[Path], None] | None = None) -> Version:
    """Write ``doc`` (the refreshed calibration) to ``out`` and as a new version of its
    device in ``store`` (and, given ``write_rrd``, its recording to ``rrd``), in one
    transaction: all are there afterwards, or none changed."""
    from imucal.io.atomic import Transaction

    dev = device_of(doc, device, str(calibration))
    if store.exists() and not store.is_dir():
        raise ImucalError("is a file; expected the store's folder", source=str(store),
                          field="--store")
    at = _second(naming._mtime(recording) or datetime.now(timezone.utc))
    # the old version's store block is that version's (refreshed_from says which it was)
    doc = {k: v for k, v in doc.items() if k != "store"} | {"device": dev, "recorded_at": iso(at),
                 "calibrated_at": datetime.now(timezone.utc).isoformat()}
    text = json.dumps(doc, indent=2, allow_nan=False) + "\n"
    folder = device_folder(store, dev)
    key = content_key(doc)
    stamp = at.strftime(STAMP)
    with locked(folder / DEVICE_LOCK):  # another add picks its name after this one's is taken
        same: dict[int, Path] = {}
        for p in folder.glob(f"{stamp}*{SUFFIX}"):
            m = NAME.match(p.name)
            if m is not None and m.group(1) == stamp:
                same[int(m.group(2) or 1)] = p
        there = next((p for _, p in sorted(same.items()) if _stored_key(p) == key), None)
        target = there or folder / file_name(at, max(same, default=0) + 1)
        block = {"device": dev, "calibrated_at": iso(at), "when_from": "recording mtime",
                 "added_from": str(Path(out).resolve()),
                 "added_at": iso(datetime.now(timezone.utc)),
                 "refreshed_from": _stored_path(calibration, store)}
        stored = json.dumps(doc | {"store": block}, indent=2, allow_nan=False) + "\n"
        targets = [out] if there else [out, target]
        targets += [rrd] if write_rrd is not None else []
        with Transaction(targets, inputs=inputs, exclusive=[] if there else [target]) as tx:
            tx.temp(out).write_text(text, encoding="utf-8")
            if write_rrd is not None:
                with tx.writing(rrd) as tmp:
                    write_rrd(tmp)
            if not there:
                _write_version(tx.temp(target), stored)
            tx.commit()
    from imucal.fleet.index import refresh_index

    refresh_index(store)
    return Version(dev, target, at, already=there is not None)


def _write_version(tmp: Path, text: str) -> None:
    tmp.write_text(text, encoding="utf-8")


def _stored_path(calibration: Path, store: Path) -> str | None:
    """The calibration's path inside the store, when it is one of its versions."""
    try:
        return calibration.resolve().relative_to(store.resolve()).as_posix()
    except ValueError:
        return None
