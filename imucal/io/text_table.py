"""Delimited text into a :class:`~imucal.io.file_contents.Table` of float columns.

CSV, TSV, ``;``- or whitespace-separated, with or without a header (a ``# t ax ay az`` comment
above headerless data counts as one), European decimal commas. A plain numeric table is read by
numpy's C reader; anything irregular goes a careful way (polars, imported only then) that names
the line and the field at fault.
"""

from __future__ import annotations

import io
import re
import warnings
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from imucal.errors import ImucalError, plural
from imucal.io.file_contents import Table
from imucal.io.text_cut import drop_cut_last_line
from imucal.io.text_preamble import find_table_start, is_number, sniff_separator, split_fields

if TYPE_CHECKING:
    import polars as pl


_COMMENT_LINE = re.compile(rb"(?m)^[ \t]*#[^\n]*")
COMMA_LOOK = 4096  # bytes of the body that say whether ";"-separated text has decimal commas


@dataclass(frozen=True)
class Head:
    """What the lines above a text table's rows say: its column names (None: none), its width,
    separator and preamble, and where its body starts (``body_start`` in the file's bytes after
    a BOM; ``first_line`` the body's 1-based file line)."""

    names: list[str] | None
    n_fields: int
    sep: str
    body_start: int
    first_line: int
    preamble: tuple[tuple[int, str, str], ...]


def read_head(data: bytes, source: str) -> Head:
    """The head of a text table from ``data``, the file's bytes (or its first part: a head
    that runs to the end of ``data`` is incomplete and read again from the whole file)."""
    found = find_table_start(data)
    start, end, comments = found.start, found.end, found.comments
    if start is None:
        raise ImucalError("no data: the file holds only blank or comment lines", source=source)
    first = data[start:end].decode("utf-8", errors="replace")
    sep = sniff_separator(first)
    fields = split_fields(first, sep)
    names: list[str] | None = None
    if any(tok and not is_number(tok) for tok in fields):
        names = [tok.strip().strip("\"'") for tok in fields]
        body_start = end + 1
        units, after = _units_row(data, body_start, sep, len(names))
        if units is not None:  # "s, m/s^2, ..." under the names: read as "name (unit)"
            names = [f"{n} ({u})" if u else n for n, u in zip(names, units)]
            body_start = after
    else:
        body_start = start
        names = _commented_header(comments, sep, len(fields))
    first_line = data.count(b"\n", 0, body_start) + 1  # 1-based file line of the body's start
    return Head(names, len(names) if names else len(fields), sep, body_start, first_line,
                tuple(found.pairs))


def drop_comment_lines(body: bytes) -> tuple[bytes, int]:
    """Comment lines among the rows emptied (a line's number stays its own), and how many."""
    if b"#" not in body:
        return body, 0
    return _COMMENT_LINE.subn(b"", body)


def reader_notes(source: str, cut: str | None, skipped: int) -> tuple[str, ...]:
    return ((f"{source}: {cut}",) if cut else ()) + (
        (f"{source}: {plural(skipped, 'comment line')} (#) among the rows skipped",)
        if skipped else ())


def read_text(data: bytes, source: str) -> Table:
    data = data.removeprefix(b"\xef\xbb\xbf")
    if b"\n" not in data and b"\r" in data:
        data = data.replace(b"\r", b"\n")  # classic Mac OS line endings: CR alone (issue 27)
    head = read_head(data, source)
    sep = head.sep
    body, skipped = drop_comment_lines(data[head.body_start:])
    decimal_comma = sep == ";" and b"," in body[:COMMA_LOOK]  # "1,5;2,0": European spreadsheets
    body, cut = drop_cut_last_line(body, sep, head.n_fields, decimal_comma, head.first_line)
    table = parse_body(body, sep, head.names, decimal_comma, head.first_line, source)
    table.preamble = head.preamble
    table.notes = reader_notes(source, cut, skipped)
    return table


def _units_row(data: bytes, pos: int, sep: str, n_fields: int) -> tuple[list[str] | None, int]:
    """A second header line of units (``s, g, g, g, deg/s, ...``): its fields and where the data
    start after it, or None when the line holds any number (it is data)."""
    end = data.find(b"\n", pos)
    end = len(data) if end < 0 else end
    line = data[pos:end].decode("utf-8", errors="replace").strip("\r")
    fields = [tok.strip().strip("\"'") for tok in split_fields(line, sep)]
    if (len(fields) != n_fields or not any(fields)
            or any(tok and is_number(tok) for tok in fields)
            or not all(len(tok) <= 12 and _UNIT_CHARS.match(tok) for tok in fields)):
        return None, pos
    return [tok.strip("[]()") for tok in fields], end + 1


# What a unit cell may hold: "s", "m/s^2", "[deg/s]", "(g)", "µs", "°/s", "rad s-1".
_UNIT_CHARS = re.compile(r"^[\w/^°µ²()\[\] .*-]*$")


def _commented_header(comments: list[str], sep: str, n_fields: int) -> list[str] | None:
    """Use "# t ax ay az" above headerless data (numpy.savetxt's style) as the header."""
    if not comments:
        return None
    fields = split_fields(comments[-1].lstrip("#%/").strip(), sep)
    if len(fields) == n_fields and all(fields) and not any(is_number(f) for f in fields):
        return fields
    return None


def parse_body(body: bytes, sep: str, names: list[str] | None, decimal_comma: bool,
               first_line: int, source: str, n_cols: int | None = None,
               dates: frozenset[int] | None = None) -> Table:
    """The rows of ``body``: the fast way when it is a plain numeric table, else the careful
    way. ``n_cols`` and ``dates`` (the width and the date-time columns) are given for a later
    piece of a table read a piece at a time (:mod:`imucal.io.text_pieces`), as its first piece
    found them."""
    table = _parse_fast(body, sep, names, decimal_comma, source)
    if table is None:
        table = _parse_careful(body, sep, names, decimal_comma, first_line, source, n_cols,
                               dates)
    return table


# The bytes of a plain numeric table besides its separator. Anything else goes the careful way,
# which reads some of it differently from numpy: it strips quotes, takes "NA" or "null" as
# missing, and keeps a non-ASCII blank inside a field where numpy would split on it.
_NUMBER_BYTES = b"0123456789.eE+- \t\r\n"


def _parse_fast(body: bytes, sep: str, names: list[str] | None, decimal_comma: bool,
                source: str) -> Table | None:
    """Read a plain numeric table with numpy's C reader; None unless every row is complete and
    every field a number, so that the careful path can name the line that is not.

    numpy takes ~45 ms for 50k rows of 4 and spares a plain text file the import of polars
    (~0.14 s CPU). On the bytes let through, it splits rows and fields as the careful path does
    (runs of blanks, or the separator with blanks around a field; blank lines skipped) and
    rounds each number correctly, as polars does, so the values are the same to the bit.
    """
    if decimal_comma:  # "1,5": a field with two commas is no number either way
        body = body.replace(b",", b".")
    allowed = _NUMBER_BYTES if sep == " " else _NUMBER_BYTES + sep.encode()
    if body.translate(None, allowed) or not body.strip():
        return None
    if b"\r" in body and body.count(b"\r") != body.count(b"\r\n"):
        return None  # a lone CR ends a line for numpy; the careful path deletes it
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # e.g. "input contained no data"
            matrix = np.loadtxt(io.BytesIO(body), dtype=np.float64, comments=None,
                                delimiter=None if sep == " " else sep, ndmin=2,
                                encoding="ascii")
    except Exception:  # a ragged row, an empty field, a malformed number: go the careful way
        return None
    n_rows, n_cols = matrix.shape
    if n_rows == 0 or (names is not None and n_cols != len(names)):
        return None
    return Table(source, names, n_cols, lambda i: matrix[:, i])


def _parse_careful(body: bytes, sep: str, names: list[str] | None, decimal_comma: bool,
                   first_line: int, source: str, width: int | None = None,
                   dates: frozenset[int] | None = None) -> Table:
    """Check the shape of every row, then read strings and convert column by column, so a
    ragged row or a bad field is reported with its line number."""
    import polars as pl

    whitespace = sep == " "
    clean = _clean_body(body, whitespace)
    if not clean.strip():
        raise ImucalError("no data rows after the header", source=source)
    csv_sep = "," if whitespace else sep
    nl = clean.find(b"\n")
    n_cols = width or (len(names) if names else
                       _count_fields(clean[: nl if nl >= 0 else None], csv_sep))
    lines = first_line + _content_lines(body, whitespace)
    counts = _fields_per_line(clean, csv_sep)
    bad = np.flatnonzero(counts != n_cols)
    if bad.size:
        i = int(bad[0])
        if names and np.all(counts == counts[0]):
            raise ImucalError(f"the header has {len(names)} column names but the rows have "
                              f"{counts[0]} fields", source=source, field="columns")
        raise ImucalError(f"ragged rows: line {lines[i]} has {counts[i]} fields, expected "
                          f"{n_cols} ({plural(bad.size, 'ragged row')} in all)",
                          source=source)
    keys = [f"c{i}" for i in range(n_cols)]
    # No quoting: numbers are never quoted in IMU logs, and a stray quote would swallow lines
    # (the header was split in Python; quotes around a number are stripped when converting).
    text = pl.read_csv(clean, has_header=False, separator=csv_sep, infer_schema=False,
                       new_columns=keys, encoding="utf8-lossy", quote_char=None)
    if names is None and n_cols > 1 and text.get_column(keys[-1]).null_count() == text.height:
        n_cols -= 1  # a trailing separator on every line is not a column
    if dates is None:
        first = text.row(0) if text.height else (None,) * n_cols
        dates = frozenset(i for i in range(n_cols) if first[i] is not None
                          and _DATETIME.match(first[i].strip(" \t\"'")))

    def column(i: int) -> np.ndarray:
        series = text.get_column(keys[i])
        label = f"column {names[i]!r}" if names else f"column {i + 1}"
        if i in dates:
            return _datetime_seconds(series, label, source, lines)
        if decimal_comma:
            series = series.str.replace(",", ".", literal=True)
        return series_to_float(series, label, source, lines)

    return Table(source, names, n_cols, column, seconds_cols=dates)


# A date and a time of day (ISO 8601 and its common variants): loggers write time this way.
_DATETIME = re.compile(r"^\d{4}[-/.]\d{1,2}[-/.]\d{1,2}[ T]\d{1,2}:\d{2}")


def _datetime_seconds(series: pl.Series, label: str, source: str,
                      lines: np.ndarray | None) -> np.ndarray:
    """Date-times (with or without a UTC offset) as seconds since the epoch; a field that is
    no date-time is reported with its line."""
    import polars as pl

    stripped = series.str.strip_chars().str.strip_chars("\"'")
    parsed = stripped.str.to_datetime(strict=False, time_unit="us")
    bad = (parsed.is_null() & stripped.is_not_null()).arg_true()
    if bad.len():
        row = int(bad[0])
        raise ImucalError(f"{label}: {stripped[row]!r} at {_where(row, lines)} is not a "
                          f"date-time like the first one, {stripped[0]!r}", source=source,
                          field="time")
    return (parsed.dt.epoch("us").cast(pl.Float64) / 1e6).fill_null(float("nan")).to_numpy()


def _clean_body(body: bytes, whitespace: bool) -> bytes:
    """Drop carriage returns and blank lines; in whitespace-separated text make each run of
    blanks between two fields a single comma (polars splits on one byte, not on runs).
    Vectorised: a Python loop over lines costs ~50 ms per 50k rows."""
    a = np.frombuffer(body, dtype=np.uint8)
    if whitespace:
        blank = (a == 32) | (a == 9) | (a == 13) | (a == 11) | (a == 12)
    else:
        blank = a == 13
    keep = ~blank
    out = a
    if whitespace and blank.any():
        is_field = keep & (a != 10)
        step = np.diff(blank.view(np.int8), prepend=np.int8(0), append=np.int8(0))
        starts, ends = np.flatnonzero(step == 1), np.flatnonzero(step == -1)
        inner = (starts > 0) & (ends < a.size)
        starts, ends = starts[inner], ends[inner]
        seps = starts[is_field[starts - 1] & is_field[ends]]
        out = a.copy()
        out[seps] = ord(",")
        keep[seps] = True
    out = out[keep]
    newline = out == 10
    if newline.any():  # a newline right after another (or at the start) ends a blank line
        blank_line = newline & np.concatenate(([True], newline[:-1]))
        out = out[~blank_line]
    return out.tobytes()


def _count_fields(line: bytes, sep: str) -> int:
    return line.count(sep.encode()) + 1


def _fields_per_line(clean: bytes, sep: str) -> np.ndarray:
    a = np.frombuffer(clean, dtype=np.uint8)
    newlines = np.flatnonzero(a == 10)
    n_lines = newlines.size + (0 if clean.endswith(b"\n") else 1)
    line_of_sep = np.searchsorted(newlines, np.flatnonzero(a == ord(sep)))
    return np.bincount(line_of_sep, minlength=n_lines)[:n_lines] + 1


def _content_lines(body: bytes, whitespace: bool) -> np.ndarray:
    """0-based line numbers (within ``body``) of the lines that hold something."""
    a = np.frombuffer(body, dtype=np.uint8)
    line_of_byte = np.concatenate(([0], np.cumsum(a[:-1] == 10)))
    blank = (a == 13) | (a == 10)
    if whitespace:
        blank |= (a == 32) | (a == 9) | (a == 11) | (a == 12)
    return np.unique(line_of_byte[~blank])


def series_to_float(series: pl.Series, label: str, source: str,
                     lines: np.ndarray | None) -> np.ndarray:
    """A column as float64; missing fields become NaN, text raises with its row or line."""
    import polars as pl

    dtype = series.dtype
    if dtype.is_numeric():
        return series.cast(pl.Float64).to_numpy()
    if dtype not in (pl.String, pl.Categorical, pl.Enum):
        raise ImucalError(f"{label} holds {dtype} values; expected numbers", source=source)
    stripped = series.cast(pl.String).str.strip_chars().str.strip_chars("\"'")
    missing = stripped.is_null() | stripped.str.to_lowercase().is_in(["", "na", "n/a", "null",
                                                                       "none"])
    numbers = stripped.cast(pl.Float64, strict=False)
    bad = (numbers.is_null() & ~missing).arg_true()
    if bad.len():
        row = int(bad[0])
        raise ImucalError(f"{label}: text {stripped[row]!r} at {_where(row, lines)} where a "
                          f"number was expected ({plural(bad.len(), 'bad field')} in all)",
                          source=source)
    return numbers.fill_null(float("nan")).to_numpy()


def _where(row: int, lines: np.ndarray | None) -> str:
    """Where a row of the table stands in the file, for messages."""
    return f"line {lines[row]}" if lines is not None and row < lines.size else f"row {row}"
