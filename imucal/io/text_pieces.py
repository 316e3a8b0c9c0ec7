"""A long text table read a piece at a time into the spill (method.md §0; issue 12's path for
text, issue 25's session.csv).

:func:`imucal.io.text_table.read_text` holds the whole file, a copy of its body and the parsed
matrix at once: 3 to 4 times the file (a 1 GB CSV of 2 hours at 1 kHz needs 3 GB). Here the
body is read in pieces of whole lines (:data:`PIECE_BYTES`), each parsed by the same two readers
(numpy's for a plain numeric piece, polars' careful one otherwise) into columns allocated by
the session's :class:`~imucal.io.spill.Spill`, mapped from a temporary file when large: the
process holds one piece of text and its rows, whatever the file's length. Each field is parsed
by the same code as before, so every value is the same to the bit.

What the whole reader decides over the whole table is decided the same way: the header, the
units row and the preamble from the file's head; the table's width and its date-time columns
from the first piece; the decimal comma from the body's first 4096 bytes; a cut last line on
the last piece (with the line before it). A piece that the whole reader would refuse (a ragged
row, a field that is no number) is read again the whole way, so that the error is the one it
gives today, word for word (its counts are over the whole file): only a file that is refused
pays for the whole read. A column that holds text is refused only if a layout asks for it, as
the whole reader's columns are converted only when asked for.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from imucal.errors import ImucalError
from imucal.io import text_table
from imucal.io.file_contents import Table
from imucal.io.spill import Spill
from imucal.io.text_cut import drop_cut_last_line
from imucal.io.text_table import (
    Head,
    drop_comment_lines,
    parse_body,
    read_head,
    read_text,
    reader_notes,
)

PIECE_BYTES = 8 << 20  # text parsed at once: ~60 000 rows of 7 fields, ~4 MB of rows
HEAD_BYTES = 1 << 20  # what the head (preamble, header, units row) is read from
_BOM = b"\xef\xbb\xbf"
_ROWS = 1 << 16


class _WholeWay(Exception):
    """This file is read the whole way (read_text): something a piece cannot settle alone."""


def read_text_pieces(path: Path, source: str, store: Spill) -> Table:
    """The table of the text file at ``path``, read a piece at a time into ``store``'s arrays;
    the same table as ``read_text(path.read_bytes(), source)`` (the same values, notes and
    errors)."""
    try:
        return _read(path, source, store)
    except ImucalError as e:
        if e.field == "spill":
            raise  # no room for the spill: said as for a long .mat, not read into memory
    except (_WholeWay, Exception):  # noqa: BLE001  # a parser's failure: the whole read says it
        pass
    return read_text(path.read_bytes(), source)  # says what is wrong, as it always did


def _read(path: Path, source: str, store: Spill) -> Table:
    with path.open("rb") as fh:
        head_bytes = fh.read(HEAD_BYTES)
    bom = len(_BOM) if head_bytes.startswith(_BOM) else 0
    data = head_bytes[bom:]
    if b"\n" not in data:
        raise _WholeWay  # CR line endings, or a head longer than HEAD_BYTES
    head = read_head(data, source)
    if head.body_start >= len(data):
        raise _WholeWay  # the head may run on past what was read
    body_at = bom + head.body_start
    reader = _Pieces(head, source, store, _count_newlines(path, body_at) + 1)
    for piece, first_line, last in _pieces(path, body_at, head.first_line):
        reader.add(piece, first_line, last)
    return reader.table(lambda: read_text(path.read_bytes(), source))


class _Pieces:
    """The columns of a table filled piece by piece: ``raw[i, :rows]`` holds column ``i``."""

    def __init__(self, head: Head, source: str, store: Spill, rows_most: int) -> None:
        self.head, self.source, self.store = head, source, store
        self.rows_most = rows_most  # newlines in the body, + 1: no more rows than that
        self.raw: np.ndarray | None = None
        self.rows = 0
        self.n_cols = 0
        self.dates: frozenset[int] = frozenset()
        self.decimal_comma = False
        self.bad: set[int] = set()  # columns with a field that is no number: refused if used
        self.skipped = 0
        self.cut: str | None = None

    def add(self, piece: bytes, first_line: int, last: bool) -> None:
        head = self.head
        piece, skipped = drop_comment_lines(piece)
        self.skipped += skipped
        first = self.raw is None
        if first and head.sep == ";":
            look = text_table.COMMA_LOOK  # the whole reader judges the decimal comma on that
            if len(piece) < look and not last:
                raise _WholeWay
            self.decimal_comma = b"," in piece[:look]
        if last:
            if not first and _content_lines(piece) < 2:
                raise _WholeWay  # a cut last line is judged against the line before it
            piece, self.cut = drop_cut_last_line(piece, head.sep, head.n_fields,
                                                 self.decimal_comma, first_line)
        if not piece.strip():
            if first and last:
                raise _WholeWay  # no rows at all: said by the whole reader
            return  # blank lines and comments alone
        table = parse_body(piece, head.sep, head.names, self.decimal_comma, first_line,
                           self.source, n_cols=head.n_fields,
                           dates=None if first else self.dates)
        if first:
            self.n_cols, self.dates = table.n_cols, table.seconds_cols
            self.raw = self.store.empty((table.n_cols, self.rows_most))
        elif table.n_cols != self.n_cols:
            raise _WholeWay  # a trailing separator on the lines of some pieces only
        n = len(table.column(0))
        if self.rows + n > self.rows_most:
            raise _WholeWay  # cannot happen (every row but the last ends in a newline)
        assert self.raw is not None
        for i in range(self.n_cols):
            out = self.raw[i, self.rows:self.rows + n]
            try:
                out[:] = table.column(i)
            except ImucalError:  # text in a column that no layout may ask for
                self.bad.add(i)
                out[:] = np.nan
        self.rows += n
        self.store.release(self.raw)  # what was written waits in the page cache, not here

    def table(self, whole: Callable[[], Table]) -> Table:
        """The table read; ``whole`` reads the file the whole way, for a column that holds
        text (its error, word for word, when a layout asks for that column)."""
        if self.raw is None:
            raise _WholeWay
        raw, rows, bad, store = self.raw, self.rows, self.bad, self.store

        def column(i: int) -> np.ndarray:
            return whole().column(i) if i in bad else raw[i, :rows]

        def stack(cols: list[int]) -> np.ndarray:
            """``np.column_stack`` of the columns, a chunk of rows at a time into the spill:
            no signal-sized array in memory when it maps."""
            columns = [column(c) for c in cols]
            out = store.empty((rows, len(cols)))
            for lo in range(0, rows, _ROWS):
                for j, c in enumerate(columns):
                    out[lo:lo + _ROWS, j] = c[lo:lo + _ROWS]
            store.release(raw)
            return out

        return Table(self.source, self.head.names, self.n_cols, column,
                     seconds_cols=self.dates, preamble=self.head.preamble,
                     notes=reader_notes(self.source, self.cut, self.skipped), stack=stack)


def _content_lines(piece: bytes, enough: int = 2) -> int:
    """Lines of ``piece`` that hold something other than blanks, counted up to ``enough``."""
    count = pos = 0
    while count < enough and pos < len(piece):
        end = piece.find(b"\n", pos)
        end = len(piece) if end < 0 else end
        count += bool(piece[pos:end].strip())
        pos = end + 1
    return count


def _count_newlines(path: Path, start: int) -> int:
    """Newlines in the file from byte ``start``."""
    count = 0
    with path.open("rb") as fh:
        fh.seek(start)
        while block := fh.read(PIECE_BYTES):
            count += block.count(b"\n")
    return count


def _lines_of(path: Path, start: int) -> Iterator[bytes]:
    """The file from byte ``start`` in pieces of about PIECE_BYTES that end at a newline (the
    last one where the file ends)."""
    with path.open("rb") as fh:
        fh.seek(start)
        carry = b""
        while block := fh.read(PIECE_BYTES):
            block = carry + block
            cut = block.rfind(b"\n") + 1
            piece, carry = block[:cut], block[cut:]
            if piece:
                yield piece
        if carry:
            yield carry


def _pieces(path: Path, start: int, first_line: int) -> Iterator[tuple[bytes, int, bool]]:
    """(piece, its first line's number, whether it is the last): the last piece holds at
    least two lines with something in them (a cut last line is judged against the line before
    it), else it goes out joined to the one before."""
    held: list[bytes] = []
    for piece in _lines_of(path, start):
        held.append(piece)
        if len(held) == 3:
            yield held[0], first_line, False
            first_line += held.pop(0).count(b"\n")
    if len(held) == 2 and _content_lines(held[1]) < 2:
        held = [held[0] + held[1]]
    for i, piece in enumerate(held):
        yield piece, first_line, i == len(held) - 1
        first_line += piece.count(b"\n")
