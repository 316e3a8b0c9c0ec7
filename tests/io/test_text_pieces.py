"""A long text table read a piece at a time into the spill (imucal/io/text_pieces.py): the
same session, to the bit, and the same calibration as the whole read; the same table, notes
and errors for any text. The pieces are made small here instead of the file large."""

from __future__ import annotations

import json
import mmap
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import imucal
from imucal.errors import ImucalError
from imucal.io import text_pieces
from imucal.io.calibration_file import result_to_dict
from imucal.io.spill import IN_MEMORY, Spill, SpillPolicy
from imucal.io.text_table import read_text

SAMPLE = Path(__file__).resolve().parents[2] / "sample_data" / "session.mat"
SIGNALS = ("acc", "t_acc", "gyro", "t_gyro")


def _mapped(a: np.ndarray) -> bool:
    base = a
    while isinstance(base, np.ndarray):
        base = base.base
    if isinstance(base, memoryview):
        base = base.obj
    return isinstance(base, mmap.mmap)


def _sample_csv(path: Path) -> Path:
    s = imucal.load_session(SAMPLE, spill=IN_MEMORY)
    m = np.column_stack([s.t_acc, s.acc, s.gyro])
    np.savetxt(path, m, fmt="%.17g", delimiter=",", header="t,ax,ay,az,gx,gy,gz", comments="")
    return path


def _strip(d: dict) -> dict:
    return {k: v for k, v in d.items() if k not in ("created", "elapsed_s", "software")}


def test_csv_above_the_threshold_is_read_in_pieces_into_the_spill(tmp_path, monkeypatch):
    csv = _sample_csv(tmp_path / "session.csv")
    spill_dir = tmp_path / "spill"
    spill_dir.mkdir()
    pieces: list[int] = []
    real = text_pieces._Pieces.add

    def count(self, piece, first_line, last):
        pieces.append(len(piece))
        return real(self, piece, first_line, last)

    monkeypatch.setattr(text_pieces, "PIECE_BYTES", 64 << 10)  # 1.7 MB of text: 27 pieces
    monkeypatch.setattr(text_pieces._Pieces, "add", count)
    whole = imucal.load_session(csv, spill=IN_MEMORY)
    assert pieces == []  # no spill, no pieces: the whole read
    small = SpillPolicy(directory=spill_dir, above_bytes=100_000)  # the file: 1.7 MB
    long = imucal.load_session(csv, spill=small)
    assert len(pieces) > 20 and max(pieces) <= (64 << 10) + 200
    assert whole.storage is None and long.storage is not None and str(spill_dir) in long.storage
    for name in SIGNALS:
        a, b = getattr(whole, name), getattr(long, name)
        assert not _mapped(a) and _mapped(b), name
        assert b.dtype == np.float64 and b.flags.c_contiguous and a.shape == b.shape
        assert np.array_equal(a.view(np.int64), b.view(np.int64)), name
    assert whole.notes == long.notes and whole.sha256 == long.sha256
    assert list(spill_dir.iterdir()) == []  # the spill file is unlinked at once
    d_whole = _strip(result_to_dict(imucal.calibrate(whole)))
    d_long = _strip(result_to_dict(imucal.calibrate(long)))
    assert json.dumps(d_whole, default=str) == json.dumps(d_long, default=str)


def test_csv_below_the_threshold_is_read_whole(tmp_path, monkeypatch):
    csv = _sample_csv(tmp_path / "session.csv")
    monkeypatch.setattr(text_pieces, "_read", None)  # any call would fail
    policy = SpillPolicy(directory=tmp_path, above_bytes=csv.stat().st_size + 1)
    session = imucal.load_session(csv, spill=policy)
    assert session.storage is None and not _mapped(session.acc)


def _outcome(read, data: bytes) -> tuple:
    """The names, notes, preamble and exact bits of every column, or the error message."""
    try:
        t = read(data)
        cols = [t.column(i).view(np.uint64).tolist() for i in range(t.n_cols)]
        return "ok", t.names, t.n_cols, t.notes, t.preamble, sorted(t.seconds_cols), cols
    except ImucalError as err:
        return "error", str(err)


def _pieces_reader(tmp_path: Path, piece_bytes: int):
    spill = Spill(SpillPolicy(directory=tmp_path, above_bytes=0))
    path = tmp_path / "f.txt"
    used: list[bool] = []

    def read(data: bytes):
        path.write_bytes(data)
        old = text_pieces.PIECE_BYTES
        text_pieces.PIECE_BYTES = piece_bytes
        try:
            table = text_pieces.read_text_pieces(path, "f.txt", spill)
        finally:
            text_pieces.PIECE_BYTES = old
        used.append(table.stack is not None)  # read in pieces, not the whole way
        return table

    return read, used


# What the whole reader decides over the whole table, and the errors it names a line in.
CASES = {
    "plain csv": (b"t,ax,ay\n" + b"".join(b"%d,%d.5,-%de-3\n" % (i, i, i) for i in range(40)),
                  True),
    "preamble, units row, comments among the rows": (
        b"rate,100\n\nt,ax,ay\ns,g,g\n1,2,3\n# note\n4,5,6\n7,8,9\n#x\n10,11,12\n", True),
    "BOM and CRLF": (b"\xef\xbb\xbft,x,y\r\n1,2,3\r\n4,5,6\r\n7,8,9\r\n", True),
    "whitespace, no header": (b"  1 2   3\n4\t5 6\n\n7 8 9\n10 11 12\n", True),
    "nan in a later piece (careful there only)": (
        b"a,b,c\n" + b"1,2,3\n" * 20 + b"4,nan,NA\n" + b"5,6,7\n" * 5, True),
    "trailing separator on every line": (b"1,2,\n3,4,\n5,6,\n7,8,\n", True),
    "dates in the first column": (
        b"time,x,y\n2024-01-02 10:00:00.5,1,2\n2024-01-02 10:00:01,3,4\n"
        b"2024-01-02 10:00:01.5,5,6\n", True),
    "last line cut short": (b"1,2,3\n4,5,6\n7,8,9\n10,11", True),
    "last number cut short": (b"1,2\n3,4\n5,6e-", True),
    "text in an unused column": (b"t,ax,note\n1,2,ok\n3,4,fine\n5,6,x\n", True),
    "ragged row far down": (b"1,2,3\n" * 30 + b"4,5\n" + b"6,7,8\n" * 3, False),
    "text in a column far down": (b"a,b\n" + b"1,2\n" * 30 + b"3,four\n5,6\n", True),
    "header count": (b"t,x,y\n1,2\n3,4\n5,6\n", False),
    "header only": (b"t,x\n\n\n", False),
    "blank lines at the end": (b"1 2 3\n4 5 6\n\n\n  \n", True),
    "comment lines at the end": (b"1,2,3\n4,5,6\n7,8\n#a\n#b\n", True),
}


@pytest.mark.parametrize("name", CASES)
@pytest.mark.parametrize("piece_bytes", [7, 64, 1 << 20])
def test_any_table_reads_the_same_in_pieces(tmp_path, name, piece_bytes):
    data, in_pieces = CASES[name]
    read, used = _pieces_reader(tmp_path, piece_bytes)
    assert _outcome(read, data) == _outcome(lambda b: read_text(b, "f.txt"), data)
    # A run of blank or comment lines at the end longer than a piece and the one before it
    # leaves the cut last line nothing to be judged against: read the whole way (never with
    # pieces of megabytes).
    if in_pieces and not (piece_bytes == 7 and name.endswith("at the end")):
        assert used == [True], name
    assert list(tmp_path.iterdir()) == [tmp_path / "f.txt"]


def test_a_decimal_comma_is_judged_on_the_same_bytes(tmp_path):
    data = b"t;x;y\n" + b"".join(b"%d;%d,25;-%d,5\n" % (i, i, i) for i in range(400))
    read, used = _pieces_reader(tmp_path, 1000)
    assert _outcome(read, data) == _outcome(lambda b: read_text(b, "f.txt"), data)
    assert used == [False]  # the first piece is shorter than the bytes it is judged on
    read, used = _pieces_reader(tmp_path, 5000)
    assert _outcome(read, data) == _outcome(lambda b: read_text(b, "f.txt"), data)
    assert used == [True]


_BITS = ["1", "-2.5", "3e1", ".5", "nan", "NA", '"7"', "x", ",", ",", ",", " ", "\t", "\n",
         "\n", "\n", "\r\n", "#", "1e", ";"]


@settings(max_examples=300, deadline=None)
@given(st.lists(st.sampled_from(_BITS), min_size=1, max_size=60), st.sampled_from([3, 11, 40]))
def test_any_text_reads_the_same_in_pieces(tmp_path_factory, bits, piece_bytes):
    data = "".join(bits).encode()
    if not data.strip():
        return  # refused before any reader sees it
    tmp = tmp_path_factory.mktemp("p")
    read, _ = _pieces_reader(tmp, piece_bytes)
    assert _outcome(read, data) == _outcome(lambda b: read_text(b, "f.txt"), data)


def _bad_inputs():
    from tests.io import test_bad_input as bad

    return [c for c in bad.CASES if c.__name__ in (
        "text_in_column", "ragged", "five_columns", "three_columns_no_gyro", "unknown_column",
        "nan_run", "time_backwards", "time_duplicated", "no_rate")]


@pytest.mark.parametrize("case", _bad_inputs(), ids=lambda c: c.__name__)
def test_bad_text_is_refused_in_pieces_with_the_same_line(tmp_path, monkeypatch, case):
    path, extra, word = case(tmp_path)
    kwargs: dict = {}
    if extra[:1] == ["--rate"]:
        kwargs["rate"] = float(extra[1])
    elif extra[:1] == ["--columns"]:
        role, col = extra[1].split("=")
        kwargs["columns"] = {role: col}
    errors = []
    monkeypatch.setattr(text_pieces, "PIECE_BYTES", 4096)  # the files: 100-140 kB
    for policy in (IN_MEMORY, SpillPolicy(directory=tmp_path, above_bytes=0)):
        with pytest.raises(ImucalError) as err:
            imucal.load_session(path, spill=policy, **kwargs)
        errors.append(str(err.value))
    assert errors[0] == errors[1] and word.lower() in errors[0].lower()
    assert "\n" not in errors[0]


def test_no_room_for_the_spill_is_said_as_for_a_mat(tmp_path, monkeypatch):
    import errno
    import os

    def full(fd, offset, length):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    csv = _sample_csv(tmp_path / "session.csv")
    spill_dir = tmp_path / "spill"
    spill_dir.mkdir()
    monkeypatch.setattr(os, "posix_fallocate", full)
    monkeypatch.setattr(text_pieces, "read_text", None)  # never read into memory instead
    with pytest.raises(ImucalError) as e:
        imucal.load_session(csv, spill=SpillPolicy(directory=spill_dir, above_bytes=0))
    assert e.value.field == "spill" and str(spill_dir) in str(e.value)
    assert "session.csv" in str(e.value) and list(spill_dir.iterdir()) == []
