"""What a file holds, stream by stream, before anything is calibrated (``imucal inspect``): each
stream's kind, name, samples, rate, unit, duration, gaps and frame, and which of them the
commands take by default, so that a user knows what to ask for.

A log of many streams (:mod:`imucal.io.formats`) is listed as its reader finds it; a table or a
.mat file is listed as the loader reads it (its accelerometer and gyroscope).
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from imucal.errors import ImucalError
from imucal.io.readers import display_name
from imucal.io.select import choose
from imucal.streams import Stream, first_of_kind


@dataclass(frozen=True)
class StreamLine:
    """One stream as ``imucal inspect`` shows it."""

    kind: str
    name: str
    samples: int
    rate_hz: float | None
    unit: str | None
    duration_s: float
    gaps: int
    frame: str | None
    device: str | None
    time_source: str
    first: list[float]
    last: list[float]
    picked: bool  # what calibrate, apply, noise, view and batch take without a selector
    # (the accelerometer and gyroscope, and the first magnetometer, which calibrate fits too)


@dataclass(frozen=True)
class FileLines:
    """A file's streams, or the one-line reason it could not be listed."""

    file: str
    format: str
    streams: tuple[StreamLine, ...]
    notes: tuple[str, ...]
    error: str | None = None
    # Several accelerometers: each as logged against the first (method.md §11), one line each.
    imus: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _line(s: Stream, picked: bool) -> StreamLine:
    return StreamLine(kind=s.kind, name=s.instance, samples=s.samples, rate_hz=s.rate,
                      unit=s.unit, duration_s=s.duration, gaps=s.gaps(), frame=s.frame,
                      device=s.device, time_source=s.time_source,
                      first=[float(v) for v in s.values[0]] if s.samples else [],
                      last=[float(v) for v in s.values[-1]] if s.samples else [],
                      picked=picked)


def inspect_file(path: str | os.PathLike[str], **load_kw: Any) -> FileLines:
    """The streams of ``path``. ``load_kw`` are :func:`~imucal.io.load.load_session`'s options,
    used for a table (its rate, columns, units). Never raises for a bad file: the error is in
    the result, so that a list of files is listed to its end."""
    from imucal.io.load import load_session
    from imucal.io.logs import log_format, read_log

    p = Path(path)
    name = display_name(p)
    try:
        key = log_format(p) if p.exists() else None
        if key is not None:
            from imucal.io.formats import FORMATS

            streams = read_log(p, key, name)
            try:
                chosen = choose(streams, {}, acc_only=False)
                picked = {id(chosen.acc), id(chosen.gyro)} | _first_mag(chosen.others)
                said = chosen.said
            except ImucalError as e:  # nothing to calibrate: listed all the same, and said
                picked, said = set(), (e.problem,)
            return FileLines(name, FORMATS[key][1],
                             tuple(_line(s, id(s) in picked) for s in streams.streams),
                             streams.notes + said, imus=_imus(streams.streams, picked))
        sess = load_session(p, **load_kw)
        pair = _session_streams(sess)
        mag = _first_mag(sess.others)
        return FileLines(name, "table", tuple(_line(s, True) for s in pair)
                         + tuple(_line(s, id(s) in mag) for s in sess.others), sess.notes)
    except ImucalError as e:
        return FileLines(name, "", (), (), error=str(e))


def _first_mag(others) -> set[int]:
    """The magnetometer calibrate takes beside the pair: the first (stages/mag.py)."""
    mag = first_of_kind(others, "mag")
    return set() if mag is None else {id(mag)}


def _imus(streams: tuple[Stream, ...], picked: set[int]) -> tuple[str, ...]:
    """Two or more accelerometers: each as logged against the one calibrate takes (method.md
    §11); nothing for one."""
    from imucal.stages.triads import logged_imus, logged_lines

    accs = sorted((s for s in streams if s.kind == "acc" and s.samples),
                  key=lambda s: id(s) not in picked)
    if len(accs) < 2:
        return ()
    return tuple(logged_lines(logged_imus(accs, [s for s in streams if s.kind == "temp"])))


def _session_streams(sess) -> list[Stream]:
    """A loaded session's sensors as streams (their unit as the loader settled it)."""
    out = [Stream("acc", "accelerometer", np.asarray(sess.t_acc), np.asarray(sess.acc),
                  sess.acc_unit, sess.source, time_source="time column or rate")]
    if sess.has_gyro:
        out.append(Stream("gyro", "gyroscope", np.asarray(sess.t_gyro), np.asarray(sess.gyro),
                          sess.gyro_unit, sess.source, time_source="time column or rate"))
    return out


def as_text(lines: FileLines) -> list[str]:
    """The lines ``imucal inspect`` prints for one file."""
    if lines.error is not None:
        return [f"{lines.error}"]
    out = [f"{lines.file} ({lines.format}): {len(lines.streams)} stream"
           f"{'' if len(lines.streams) == 1 else 's'}"]
    width = max((len(s.name) for s in lines.streams), default=0)
    for s in lines.streams:
        rate = f"{s.rate_hz:8.2f} Hz" if s.rate_hz else "       - Hz"
        extra = ", ".join(x for x in (s.frame, s.device and f"device {s.device}") if x)
        out.append(f"  {'*' if s.picked else ' '} {s.kind:<4} {s.name:<{width}}  "
                   f"{s.samples:>9} samples {rate}  {s.unit or 'unit ?':<8} "
                   f"{s.duration_s:8.1f} s  {s.gaps} gap{'' if s.gaps == 1 else 's'}"
                   + (f"  ({extra})" if extra else ""))
    if any(s.picked for s in lines.streams):
        out.append("  * taken by calibrate, apply, noise, view and batch unless --acc/--gyro/"
                   "--mag name others")
    out += [f"  note: {n}" for n in lines.notes]
    if lines.imus:
        out += [f"  {lines.imus[0]}:"] + [f"    {t}" for t in lines.imus[1:]]
    return out


__all__ = ["FileLines", "StreamLine", "as_text", "inspect_file"]
