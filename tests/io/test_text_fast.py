"""The numpy fast path for plain numeric text must agree, to the bit, with the careful path that
reports bad lines: the careful path is the definition, the fast one only saves time (and the
import of polars)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from imucal.errors import ImucalError
from imucal.io import text_table
from imucal.io.file_contents import Table

# How loggers and savetxt write numbers; the repr-like ones round-trip a float exactly.
EXACT_FORMATS = ["repr", "%.17g", "%.17e"]
FORMATS = [*EXACT_FORMATS, "%.7e", "%15.7e", "%g", "%.6f", "%.3f"]


def _fmt(value: float, fmt: str) -> str:
    return repr(value) if fmt == "repr" else fmt % value


def _read(data: bytes, fast: bool = True) -> tuple[Table, bool]:
    """``_read_text`` with or without the fast path; also says whether the fast path answered."""
    calls: list[bool] = []
    real = text_table._parse_fast

    def spy(*args):
        table = real(*args) if fast else None
        calls.append(table is not None)
        return table

    text_table._parse_fast = spy
    try:
        return text_table.read_text(data, "f.txt"), calls == [True]
    finally:
        text_table._parse_fast = real


def _columns(table: Table) -> np.ndarray:
    return np.column_stack([table.column(i) for i in range(table.n_cols)])


def _outcome(data: bytes, fast: bool) -> tuple:
    """What reading gives: the names and the exact bits of every value, or the error message."""
    try:
        table, _ = _read(data, fast)
        return "ok", table.names, _columns(table).view(np.uint64).tolist()
    except ImucalError as err:
        return "error", str(err)


finite = st.one_of(
    st.floats(allow_nan=False, allow_infinity=False),  # any magnitude, subnormals, -0.0
    st.floats(-1e5, 1e5, allow_nan=False),
    st.integers(-(2**53), 2**53).map(float),
)


@st.composite
def tables(draw):
    style = draw(st.sampled_from(["csv", "tsv", "semicolon", "decimal comma", "savetxt",
                                  "imu_tk"]))
    header = draw(st.sampled_from([None, "plain", "commented"]))
    # Decimal commas are recognised from a header of two or more ";"-separated names: the
    # first line "1,5;2" alone would be sniffed as comma-separated.
    one_column_ok = style != "decimal comma"
    if not one_column_ok:
        header = "plain"
    n_rows, n_cols = draw(st.integers(1, 30)), draw(st.integers(1 if one_column_ok else 2, 8))
    matrix = np.array(draw(st.lists(st.lists(finite, min_size=n_cols, max_size=n_cols),
                                    min_size=n_rows, max_size=n_rows)), dtype=np.float64)
    fmt = draw(st.sampled_from([*FORMATS, "int"]))
    if fmt == "int":
        matrix = np.trunc(np.clip(matrix, -1e15, 1e15))
    newline = draw(st.sampled_from(["\n", "\r\n"]))
    return matrix, fmt, style, header, newline


def _write(matrix: np.ndarray, fmt: str, style: str, header: str | None,
           newline: str) -> tuple[bytes, list[list[str]]]:
    sep = {"csv": ",", "tsv": "\t", "semicolon": ";", "decimal comma": ";", "savetxt": " ",
           "imu_tk": "   "}[style]
    cells = [[str(int(v)) if fmt == "int" else _fmt(float(v), fmt) for v in row] for row in matrix]
    if style == "decimal comma":
        cells = [[c.replace(".", ",") for c in row] for row in cells]
    lead = "   " if style == "imu_tk" else ""
    lines = [lead + sep.join(row) for row in cells]
    names = [f"c{i}" for i in range(matrix.shape[1])]
    if header == "plain":
        lines.insert(0, sep.join(names))
    elif header == "commented":  # numpy.savetxt(header=...)
        lines.insert(0, "# " + sep.join(names))
    return (newline.join(lines) + newline).encode(), cells


@settings(max_examples=300, deadline=None)
@given(tables())
def test_fast_path_equals_careful_path_and_the_written_values(case):
    matrix, fmt, style, header, newline = case
    data, cells = _write(*case)
    table, used_fast = _read(data)
    assert used_fast, data[:200]
    careful, _ = _read(data, fast=False)
    fast_values, careful_values = _columns(table), _columns(careful)
    assert table.names == careful.names and table.n_cols == careful.n_cols == matrix.shape[1]
    assert np.array_equal(fast_values.view(np.uint64), careful_values.view(np.uint64))
    written = np.array([[float(c.replace(",", ".")) for c in row] for row in cells])
    assert np.array_equal(fast_values, written)
    if fmt in EXACT_FORMATS or fmt == "int":
        assert np.array_equal(fast_values, matrix)


# Bodies the two parsers could read differently. The fast path either gives the careful path's
# answer or leaves the file to it; ``fast`` says which is expected.
EDGE_CASES = {
    "crlf": (b"1,2\r\n3,4\r\n", True),
    "last line without newline": (b"1 2\n3 4", True),
    "blank lines in the middle and at the end": (b"1 2\n\n3 4\n\n\n", True),
    "whitespace-only line in whitespace text": (b"1 2\n  \t \n3 4\n", True),
    "blanks around csv fields": (b"1, 2\n 3 ,4 \n", True),
    "tab inside whitespace text": (b"1 2\n3\t4\n", True),
    "overflow and underflow": (b"1e400 1e-400\n-0 +5\n", True),
    "decimal comma": (b"t;x\n1,5;2\n-3,25e1;,5\n", True),
    "whitespace-only line in csv": (b"1,2\n  \n3,4\n", False),
    "trailing separator on every line": (b"1,2,\n3,4,\n", False),
    "trailing separator on the last line only": (b"1,2\n3,4,", False),
    "empty field": (b"1,,2\n3,4,5\n", False),
    "ragged": (b"1 2 3\n4 5\n6 7 8\n", False),
    "last line cut short (dropped before either path)": (b"1 2 3\n4 5\n", True),
    "last number cut short (dropped before either path)": (b"1,2\n3,4e-", True),
    "lone carriage return": (b"1 2\r3 4\n", False),
    "quoted numbers": (b'"1","2"\n"3","4"\n', False),
    "nan and inf": (b"nan 1\n-inf 2\n", False),
    "missing as NA": (b"1,2\n3,NA\n", False),
    "underscores": (b"1_000 2\n3 4\n", False),
    "hex": (b"1 2\n0x10 4\n", False),
    "no-break space between fields": ("1\u00a02\n3 4\n".encode(), False),
    "vertical tab as a blank": (b"1\x0b2\n3 4\n", False),
    "decimal comma with two commas": (b"t;x\n1,000,5;2\n3;4\n", False),
    "header count": (b"t x y\n1 2\n3 4\n", False),
    "header only": (b"t,x\n\n", False),
    "text": (b"1 2\n3 four\n", False),
    # Lines of no-break spaces only: no fields at all (found by the random test: IndexError).
    "no-break spaces only": ("\u00a0\n\u00a0".encode(), False),
}


@pytest.mark.parametrize("name", EDGE_CASES)
def test_edge_cases_read_as_the_careful_path_reads_them(name):
    data, fast = EDGE_CASES[name]
    assert _outcome(data, fast=True) == _outcome(data, fast=False)
    try:
        _, used_fast = _read(data)
    except ImucalError:
        used_fast = False
    assert used_fast == fast


_PIECES = ["1", "-2.5", "3e1", "4.", ".5", "+6", "1e400", "e", "-", ".", "nan", "1_0", '"7"',
           "1,5", ",", ";", " ", "  ", "\t", "\n", "\r\n", "\r", "\x0b", "\u00a0", "#", "NA"]


@settings(max_examples=500, deadline=None)
@given(st.lists(st.sampled_from(_PIECES), min_size=1, max_size=40))
def test_any_text_reads_the_same_with_and_without_the_fast_path(pieces):
    data = "".join(pieces).encode()
    if not data.strip():
        return  # _read_file refuses an empty file before any parser sees it
    assert _outcome(data, fast=True) == _outcome(data, fast=False)
