"""A long recording as a sequence of small sessions, read a chunk at a time.

Each chunk goes through :func:`imucal.io.load.load_session` itself (same column, unit and time
rules as every other command): the chunk's lines, behind the file's own header lines, are
written to a small file in a temporary directory, under the original file's name, and loaded.
Memory is bounded by the chunk (``chunk_bytes`` of text, or the Parquet rows of the same
fraction of the file), never by the recording.

- Text (CSV/TSV/whitespace): cut at line ends into equal fractions of the body.
- Parquet: cut into equal fractions of its rows (read with a row slice).
- MATLAB .mat (v5 or v7.3): read whole, in one chunk (a compressed v5 file cannot be read in
  parts); the notes say so.

A two-file session (accelerometer and ``--gyro`` file) is cut into the same number of chunks,
each the same fraction of its file, so the two stay roughly in step.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from imucal.errors import ImucalError
from imucal.io.input_files import check_gyro_file, refuse_special
from imucal.io.load import load_session
from imucal.io.readers import display_name
from imucal.session import Session

CHUNK_BYTES = 16 << 20  # about 16 MB of text per chunk: 250k rows of a 7-column CSV
_PARQUET = b"PAR1"
_BINARY = (b"MATLAB 5.0 MAT-file", b"\x89HDF\r\n\x1a\n")
_COMMENT = (b"#", b"%", b"//")


@dataclass(frozen=True)
class _Plan:
    """How one file is cut: ``kind`` "text", "parquet" or "whole"."""

    path: Path
    kind: str
    header: bytes = b""  # text: the lines before the first data line
    body_start: int = 0  # text: byte offset of the first data line
    size: int = 0  # text: bytes; parquet: rows


def _is_number(tok: bytes) -> bool:
    try:
        float(tok.replace(b",", b"."))
    except ValueError:
        return False
    return True


def _header_end(path: Path) -> int:
    """Byte offset of the first data line: the lines before it are blank, comments, or end in
    a word (a header row, a row of units)."""
    with path.open("rb") as f:
        head = f.read(1 << 16)
    pos = 0
    for line in head.splitlines(keepends=True):
        text = line.strip().removeprefix(b"\xef\xbb\xbf")
        if text and not text.startswith(_COMMENT):
            last = text.replace(b";", b",").replace(b"\t", b",").split(b",")[-1].split()
            if last and _is_number(last[-1].strip(b"\"'")):
                return pos
        pos += len(line)
    return pos


def _plan(path: Path) -> _Plan:
    if not path.exists():
        raise ImucalError("file not found", source=str(path))
    refuse_special(path.stat().st_mode, display_name(path))
    from imucal.io.formats import sniff

    if path.is_dir() and sniff(b"", path):
        return _Plan(path, "whole")  # a ROS 2 bag's folder: its chosen topics, read whole
    try:
        with path.open("rb") as f:
            head = f.read(1024)
    except OSError as e:  # permission: the file named, as every reader says it
        raise ImucalError(f"cannot be read ({e.strerror or e})", source=display_name(path)
                          ) from None
    if sniff(head):
        return _Plan(path, "whole")  # a log of many streams: only the chosen ones are read
    if head[:4] == _PARQUET:
        import polars as pl

        rows = int(pl.scan_parquet(path).select(pl.len()).collect().item())
        return _Plan(path, "parquet", size=rows)
    if head.startswith(_BINARY[0]) or head[:8] == _BINARY[1] or head[512:520] == _BINARY[1]:
        return _Plan(path, "whole")
    start = _header_end(path)
    with path.open("rb") as f:
        header = f.read(start)
    return _Plan(path, "text", header=header, body_start=start,
                 size=os.path.getsize(path) - start)


def _text_cuts(plan: _Plan, n: int) -> list[int]:
    """Byte offsets of n + 1 cut points at line ends (the first the body's start)."""
    cuts = [plan.body_start]
    end = plan.body_start + plan.size
    with plan.path.open("rb") as f:
        for j in range(1, n):
            target = plan.body_start + plan.size * j // n
            f.seek(max(target, cuts[-1]))
            f.readline()  # to the end of the line the target falls in
            cuts.append(min(f.tell(), end))
    cuts.append(end)
    return cuts


def _write_piece(plan: _Plan, j: int, n: int, cuts: list[int] | None, out: Path) -> bool:
    """Write chunk j of n of the file to ``out``; False if it is empty."""
    if plan.kind == "text":
        assert cuts is not None
        lo, hi = cuts[j], cuts[j + 1]
        if hi <= lo:
            return False
        with plan.path.open("rb") as f, out.open("wb") as g:
            g.write(plan.header)
            f.seek(lo)
            g.write(f.read(hi - lo))
        return True
    import polars as pl

    lo, hi = plan.size * j // n, plan.size * (j + 1) // n
    if hi <= lo:
        return False
    pl.scan_parquet(plan.path).slice(lo, hi - lo).collect().write_parquet(out)
    return True


def iter_chunks(path: str | os.PathLike, *, gyro_path: str | os.PathLike | None = None,
                chunk_bytes: int = CHUNK_BYTES, **load_kw: Any) -> Iterator[Session]:
    """The recording as consecutive sessions of about ``chunk_bytes`` each (see the module
    docstring). ``load_kw`` are :func:`load_session`'s options; the first chunk's resolved
    accelerometer unit is given to the later ones, so a guess is made once."""
    if gyro_path is not None:  # pieces of one file are two files: check the files themselves
        check_gyro_file([Path(path), Path(gyro_path)], load_kw.get("acc_only", False))
    plans = [_plan(Path(path))] + ([_plan(Path(gyro_path))] if gyro_path is not None else [])
    if any(p.kind == "whole" for p in plans):
        sess = load_session(path, gyro_path=gyro_path, **load_kw)
        yield replace(sess, notes=sess.notes + ("MATLAB .mat files are read whole, not in "
                                                "chunks: memory grows with the recording",))
        return
    n = max(1, max(-(-p.size // chunk_bytes) if p.kind == "text" else
                   -(-p.size // max(1, chunk_bytes // 64)) for p in plans))
    cuts = [_text_cuts(p, n) if p.kind == "text" else None for p in plans]
    kw = dict(load_kw)
    with tempfile.TemporaryDirectory(prefix="imucal-chunks-") as tmp:
        pieces = [Path(tmp) / f"{i}" / display_name(p.path) for i, p in enumerate(plans)]
        for piece in pieces:
            piece.parent.mkdir()
        for j in range(n):
            try:
                have = [_write_piece(p, j, n, c, piece)
                        for p, c, piece in zip(plans, cuts, pieces)]
            except OSError as e:  # a full disk: say which file and where (issue 27)
                raise ImucalError(f"cannot write chunk {j + 1} of {n} to the temporary folder "
                                  f"{tmp} ({e.strerror or e}); free space there or set TMPDIR",
                                  source=display_name(Path(path))) from None
            if not all(have):
                continue
            try:
                sess = load_session(pieces[0], gyro_path=pieces[1] if len(pieces) > 1 else None,
                                    **kw)
            except ImucalError as e:
                where = f"chunk {j + 1} of {n}" if n > 1 else None
                raise ImucalError(e.problem, source=e.source,
                                  field=", ".join(x for x in (where, e.field) if x)) from None
            if kw.get("acc_unit", "auto") == "auto":
                kw["acc_unit"] = sess.acc_unit
            yield sess


def continuous_time(t: np.ndarray, last: float | None) -> np.ndarray:
    """Timestamps made from a rate restart at 0 in every chunk: shift them to follow ``last``
    (one median step after it). Times that already follow are returned as they are."""
    if last is None or len(t) == 0 or t[0] > last:
        return t
    step = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    return t + (last + step - t[0])
