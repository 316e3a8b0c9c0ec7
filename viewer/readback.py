"""Read a recording back: the numbers behind the plots, for scripts and tests.

Uses ``rerun.chunk.RrdReader`` (no extra packages). Paths as in :mod:`viewer.paths`::

    t, v = scalars("run.rrd", "imu/accelerometer/magnitude")   # v[:, 1] = calibrated |a|
    lam = values("run.rrd", "lcurve/corner")["lambda"]
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np
from rerun.chunk import RrdReader


def _path(entity: str) -> str:
    return entity if entity.startswith("/") else "/" + entity


def _batches(rrd: str | os.PathLike, entity: str, static: bool) -> list:
    stream = RrdReader(rrd).stream().filter(content=_path(entity), is_static=static)
    return [c.to_record_batch() for c in stream.to_chunks()]


def _index(batch, timeline: str) -> np.ndarray:
    """A batch's timeline column: seconds for a duration timeline, integers for a sequence."""
    col = batch.column(timeline)
    if str(col.type).startswith("duration"):
        return col.cast("int64").to_numpy() / 1e9
    return col.to_numpy()


def scalars(rrd: str | os.PathLike, entity: str, timeline: str = "time"
            ) -> tuple[np.ndarray, np.ndarray]:
    """Index (seconds for ``time``, integers for sequences) and values, (N,) or (N, k),
    sorted by the index."""
    idx, vals = [], []
    for b in _batches(rrd, entity, static=False):
        names = b.schema.names
        if timeline not in names or "Scalars:scalars" not in names:
            continue
        idx.append(_index(b, timeline))
        lists = b.column("Scalars:scalars")
        flat = lists.flatten().to_numpy()
        vals.append(flat.reshape(len(b), -1))
    if not idx:
        return np.zeros(0), np.zeros(0)
    t = np.concatenate(idx)
    v = np.concatenate(vals)
    order = np.argsort(t, kind="stable")
    v = v[order]
    return t[order], (v[:, 0] if v.shape[1] == 1 else v)


def column(rrd: str | os.PathLike, entity: str, component: str, timeline: str = "time"
           ) -> tuple[np.ndarray, list]:
    """Any temporal component (e.g. ``Arrows3D:vectors``, ``StateChange:state``) as Python
    values, with its index."""
    idx, vals = [], []
    for b in _batches(rrd, entity, static=False):
        if component not in b.schema.names or timeline not in b.schema.names:
            continue
        idx.append(_index(b, timeline))
        vals += b.column(component).to_pylist()
    t = np.concatenate(idx) if idx else np.zeros(0)
    order = np.argsort(t, kind="stable")
    return t[order], [vals[i] for i in order]


def values(rrd: str | os.PathLike, entity: str) -> dict[str, Any]:
    """The static components of an entity (AnyValues and archetype fields): one-element
    lists become scalars."""
    out: dict[str, Any] = {}
    for b in _batches(rrd, entity, static=True):
        for name in b.schema.names:
            if name.startswith("rerun."):
                continue
            v = b.column(name).to_pylist()[-1]
            if isinstance(v, list) and len(v) == 1:
                v = v[0]
            out[name] = v
    return out


def entities(rrd: str | os.PathLike) -> dict[str, int]:
    """Temporal rows per entity path (static rows not counted), from the file's manifest."""
    rows: dict[str, int] = {}
    for line in RrdReader(rrd).store().summary().splitlines():
        parts = line.split()
        if not parts:
            continue
        key = parts[0].lstrip("/")
        rows.setdefault(key, 0)
        if "static=False" in parts:
            rows[key] += int(next(p for p in parts if p.startswith("rows="))[5:])
    return rows


def _blueprint_column(rrd: str | os.PathLike, prefix: str, component: str) -> dict[str, Any]:
    reader = RrdReader(rrd)
    stores = reader.blueprints()
    out: dict[str, Any] = {}
    if not stores:
        return out
    for chunk in reader.stream(store=stores[0]).filter(content=f"/{prefix}/**").to_chunks():
        b = chunk.to_record_batch()
        if component in b.schema.names:
            v = b.column(component).to_pylist()[-1]
            while isinstance(v, list) and len(v) == 1:
                v = v[0]
            out[chunk.entity_path] = v
    return out


def blueprint_views(rrd: str | os.PathLike) -> list[tuple[str, str]]:
    """(view class, view name) of every view in the layout stored in the file."""
    classes = _blueprint_column(rrd, "view", "ViewBlueprint:class_identifier")
    names = _blueprint_column(rrd, "view", "ViewBlueprint:display_name")
    return sorted((c, names.get(k, "")) for k, c in classes.items())


def blueprint_containers(rrd: str | os.PathLike) -> list[str]:
    """Names of the named containers (the tabs) of the stored layout."""
    names = _blueprint_column(rrd, "container", "ContainerBlueprint:display_name")
    return sorted(names.values())
