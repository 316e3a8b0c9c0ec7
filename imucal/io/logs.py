"""A log of many sensor streams (a ROS bag, a ULog, a DataFlash log, :mod:`imucal.io.formats`):
recognised from its first bytes, read with at most one line of error, and the streams to
calibrate chosen from it (:mod:`imucal.io.select`), every choice said."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from imucal.errors import ImucalError
from imucal.io.parts import LoadOptions
from imucal.io.select import Choice, choose, describe, keep_for
from imucal.streams import KIND_LABELS, KINDS, StreamSet


def log_format(path: Path) -> str | None:
    """The format key of a log of many streams (:mod:`imucal.io.formats`), or None."""
    from imucal.io.formats import sniff

    try:
        if path.is_dir():
            return sniff(b"", path)
        if not path.is_file():
            return None  # a FIFO would block here: check_file says what it is
        with path.open("rb") as fh:
            return sniff(fh.read(1024), path)
    except OSError:
        return None  # check_file says what is wrong with it


def read_log(path: Path, key: str, source: str, keep=None) -> StreamSet:
    """Every stream of a log (or those ``keep`` accepts); library failures in one line."""
    from imucal.io.formats import read_streams
    from imucal.io.readers import one_line_error

    try:
        return read_streams(path, key, source, keep)
    except ImucalError:
        raise
    except MemoryError:
        raise ImucalError("not enough memory to load the file", source=source) from None
    except Exception as exc:  # a parser's failure is a problem with the file, in one line
        raise ImucalError(f"cannot read the file: {one_line_error(exc)}", source=source) from None


def choose_streams(path: Path, key: str, source: str, select: dict[str, str | None],
                    acc_only: bool, opts: LoadOptions) -> Choice:
    keep = keep_for(select)
    streams = read_log(path, key, source, keep)
    try:
        chosen = choose(streams, select, acc_only)
    except ImucalError:
        if keep is None:
            raise
        # A selector that matched nothing read nothing: read the file's every stream, so that
        # the refusal lists what it does hold.
        streams = read_log(path, key, source)
        chosen = choose(streams, select, acc_only)
    opts.notes.extend(streams.notes)
    opts.notes.extend(chosen.said)
    for s in (chosen.acc, chosen.gyro):
        if s is not None:
            opts.notes.extend(s.notes)
            opts.notes.append(f"{KIND_LABELS[s.kind]}: {describe(s)}")
    return chosen


def check_select(select: Mapping[str, str | None] | None, source: str
                  ) -> dict[str, str | None]:
    select = dict(select or {})
    unknown = [k for k in select if k not in KINDS]
    if unknown:
        raise ImucalError(f"unknown stream kind(s) {', '.join(map(repr, unknown))}; expected "
                          f"{', '.join(KINDS)}", source=source, field="select")
    for kind, sel in select.items():
        if sel is not None and (not isinstance(sel, str) or not sel.strip()):
            raise ImucalError(f"a {kind} selector must be a stream's name, got {sel!r}",
                              source=source, field=f"--{kind}")
    return {k: None if v is None else v.strip() for k, v in select.items()}
