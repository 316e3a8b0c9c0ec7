"""Where the table of a text file begins (method.md §0), and what the lines above it say.

Loggers write a few lines before the table: blank lines, ``#``/``%``/``//`` comments, and
``key<sep>value`` metadata (``sample_rate_hz,200``, ``Update Rate: 100Hz``). They are skipped,
and their key-value pairs kept for :mod:`imucal.io.file_facts` to read a rate, a time unit or
an initial still period from. Metadata lines are told from a two-column table by what follows
them: a table of an IMU has three columns or more.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

MAX_PREAMBLE_LINES = 1000  # key-value lines looked at before a table; a longer run is no preamble

_COMMENT = (b"#", b"%", b"//")
# "key<sep>value": a key starting with a letter, then , ; tab : = or blanks, then a value that
# does not hold the same separator again (else the line is a row of three fields or more).
_KEY_VALUE = re.compile(r"^([A-Za-z_][^,;\t:=]*?)\s*([,;\t:=])\s*(.*)$")
_KEY_BLANK_VALUE = re.compile(r"^([A-Za-z_]\S*)\s+(\S+)$")


@dataclass(frozen=True)
class TableStart:
    """Offsets of the table's first line (``start`` to ``end``), the comments above it and the
    ``(line, key, value)`` pairs of its preamble (1-based file lines)."""

    start: int | None  # None: nothing but blank lines, comments and metadata
    end: int
    comments: list[str]
    pairs: list[tuple[int, str, str]]


def sniff_separator(line: str) -> str:
    for sep in (",", "\t", ";"):
        if sep in line:
            return sep
    return " "  # any run of spaces or tabs


def split_fields(line: str, sep: str) -> list[str]:
    return line.split() if sep == " " else [tok.strip() for tok in line.strip("\r\n").split(sep)]


def is_number(token: str) -> bool:
    try:
        float(token.strip().strip("\"'").replace(",", "."))
    except ValueError:
        return False
    return True


def key_value(line: str) -> tuple[str, str, str] | None:
    """``(key, value, separator)`` of a metadata line, or None for anything else."""
    line = line.strip()
    match = _KEY_VALUE.match(line)
    if match:
        key, sep, value = match.groups()
        if sep in ",;\t" and sep in value:
            return None
        return key.strip(), value.strip().strip("\"'"), sep
    match = _KEY_BLANK_VALUE.match(line)
    return (match.group(1), match.group(2), " ") if match else None


def _table_follows(line: str, seps: set[str]) -> bool:
    """Whether ``line`` can start the table after metadata lines separated by ``seps``: three
    fields or more, by its own separator and by theirs (a ``c0;c1`` header above ``1,5;2,0``
    is a two-column table with decimal commas, not metadata above three columns)."""
    own = sniff_separator(line)
    theirs = {sep for sep in seps & {",", ";", "\t"} if sep in line}
    return all(len(split_fields(line, sep)) >= 3 for sep in {own} | theirs)


def find_table_start(data: bytes) -> TableStart:
    """Skip blank lines, comments and a metadata preamble up to the table's first line.

    Metadata lines count only when a line of three fields or more follows them; otherwise the
    table starts at the first of them, as it always did (a two-column table has a header that
    looks like ``key,value``)."""
    pos, line_no = 0, 0
    comments: list[str] = []
    pairs: list[tuple[int, str, str]] = []
    seps: set[str] = set()
    first: TableStart | None = None  # where the table starts if the metadata is no preamble
    while pos < len(data):
        end = data.find(b"\n", pos)
        end = len(data) if end < 0 else end
        line_no += 1
        raw = data[pos:end].strip()
        text = raw.decode("utf-8", errors="replace")
        if raw.startswith(_COMMENT):
            comments.append(text)
            pair = key_value(text.lstrip("#%/ \t"))
            if pair is not None:
                pairs.append((line_no, *pair[:2]))
        elif raw:
            pair = key_value(text) if len(pairs) < MAX_PREAMBLE_LINES else None
            if pair is None:
                if first is not None and not _table_follows(text, seps):
                    return first
                return TableStart(pos, end, comments, pairs)
            if first is None:
                first = TableStart(pos, end, list(comments), list(pairs))
            pairs.append((line_no, *pair[:2]))
            seps.add(pair[2])
        pos = end + 1
    return first or TableStart(None, 0, comments, pairs)
