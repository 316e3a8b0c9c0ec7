"""The session file (imucal/capture/writer.py): whole rows, a capture never replaces one, and a
full disk stops the writing but keeps what was written."""

import errno
import os

import pytest

from imucal.capture import writer as writer_mod
from imucal.capture.writer import SessionWriter
from imucal.errors import ImucalError


def test_rows_written_whole_and_never_replaced(tmp_path):
    w = SessionWriter(tmp_path / "D", ["t", "ax", "ay", "az"])
    w.add(["0.0,0,0,1", "0.01,0,0,1"])
    assert (tmp_path / "D" / "session.csv").read_text() == "t,ax,ay,az\n"  # not yet due
    assert w.flush(wait=False)
    w.add(["0.02,0,0,1"])
    w.close()
    assert (tmp_path / "D" / "session.csv").read_text().splitlines() == [
        "t,ax,ay,az", "0.0,0,0,1", "0.01,0,0,1", "0.02,0,0,1"]
    assert w.rows == 3
    with pytest.raises(ImucalError, match="already there"):
        SessionWriter(tmp_path / "D", ["t"])


def test_flush_is_due_after_half_a_second(tmp_path, monkeypatch):
    w = SessionWriter(tmp_path, ["t", "ax", "ay", "az"])
    w.add(["1,0,0,1"])
    assert not w.due(w.last_write + 0.49) and w.due(w.last_write + 0.5)
    w.close()


def test_a_full_disk_keeps_what_was_written(tmp_path, monkeypatch):
    w = SessionWriter(tmp_path, ["t", "ax", "ay", "az"])
    w.add(["1,0,0,1"])
    w.flush()
    real = os.write

    def full(fd, data):
        if fd == w.fd:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(fd, data)

    monkeypatch.setattr(writer_mod.os, "write", full)
    w.add(["2,0,0,1"])
    w.flush()  # no exception: the capture goes on to its end and says it
    monkeypatch.setattr(writer_mod.os, "write", real)
    w.add(["3,0,0,1"])
    w.close()
    assert "No space left" in w.error and w.rows == 1
    assert (tmp_path / "session.csv").read_text() == "t,ax,ay,az\n1,0,0,1\n"


def test_ctrl_c_during_a_write_never_writes_a_row_twice(tmp_path, monkeypatch):
    # Ctrl-C lands right after the rows reached the file, before the writer noted it: closing
    # (the capture's finally) must not write them again (a repeated time: an unreadable file).
    w = SessionWriter(tmp_path, ["t", "ax", "ay", "az"])
    real = os.write
    hits = []

    def write_then_interrupt(fd, data):
        n = real(fd, data)
        if fd == w.fd and not hits:
            hits.append(n)
            raise KeyboardInterrupt
        return n

    monkeypatch.setattr(writer_mod.os, "write", write_then_interrupt)
    w.add(["1,0,0,1", "2,0,0,1"])
    with pytest.raises(KeyboardInterrupt):
        w.flush()
    w.add(["3,0,0,1"])
    w.close()
    assert (tmp_path / "session.csv").read_text().splitlines() == [
        "t,ax,ay,az", "1,0,0,1", "2,0,0,1", "3,0,0,1"]
