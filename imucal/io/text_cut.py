"""A text log's last line cut short (method.md §0): the logger was stopped mid-write.

Such a line has fewer fields than the line before it, or ends in a number cut off before its
end ("1.5e", "-"). It is dropped with a note naming the line, instead of refusing a whole
recording for its last few bytes; a short row anywhere else stays an error, as does a last line
whose line before it is short too (then the rows are not of one width at all).
"""

from __future__ import annotations

import re

from imucal.io.text_preamble import is_number, split_fields

_BLANKS = b" \t\r\n\x0b\x0c"
# What is left of a number whose end was cut off: a sign, digits with a point, an exponent
# marker with or without its sign, but no exponent digits.
_NUMBER_PREFIX = re.compile(r"[-+]?(\d+\.?\d*|\.\d*)?([eE][-+]?)?")


def drop_cut_last_line(body: bytes, sep: str, n_fields: int, decimal_comma: bool,
                       first_line: int) -> tuple[bytes, str | None]:
    """``body`` without a cut last line, and a note saying which line was dropped (or None).

    ``n_fields`` is the table's width, ``first_line`` the file line ``body`` starts on."""
    # Offsets, not slices: the body may be a large file, and most have nothing cut.
    end = _end_of_content(body, len(body))
    start = body.rfind(b"\n", 0, end) + 1
    before_end = _end_of_content(body, start)
    if start == 0 or before_end == 0:
        return body, None  # one line: no line before it to measure against
    previous = body[body.rfind(b"\n", 0, before_end) + 1:before_end]
    if len(split_fields(previous.decode("utf-8", errors="replace"), sep)) != n_fields:
        return body, None
    fields = split_fields(body[start:end].decode("utf-8", errors="replace"), sep)
    if len(fields) < n_fields:
        why = f"has {len(fields)} of {n_fields} fields"
    elif fields and len(fields) == n_fields and _cut_number(fields[-1], decimal_comma):
        why = f"ends in {fields[-1]!r}, a number cut short"
    else:
        return body, None
    line = first_line + body.count(b"\n", 0, start)
    return body[:start], (f"dropped the last line (line {line}): it {why}, as a logger stopped "
                          "mid-write leaves it")


def _end_of_content(body: bytes, end: int) -> int:
    """``end`` moved back over blank bytes."""
    while end > 0 and body[end - 1] in _BLANKS:
        end -= 1
    return end


def _cut_number(token: str, decimal_comma: bool) -> bool:
    token = token.strip()
    if decimal_comma:
        token = token.replace(",", ".")
    return (token[:1] in tuple("+-.0123456789") and _NUMBER_PREFIX.fullmatch(token) is not None
            and not is_number(token))
