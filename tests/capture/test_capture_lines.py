"""Lines to rows: the header by the table loader's names, garbled lines counted and skipped,
partial lines joined, the time's unit, --columns and --rate (imucal/capture/lines.py)."""

import numpy as np
import pytest

from imucal.capture.lines import LineParser
from imucal.errors import ImucalError


def test_header_rows_and_garbled_lines_counted():
    p = LineParser("test")
    b = p.feed(b"booting...\nt,ax,ay,az,gx,gy,gz\n0.00,0,0,1,0.1,0.2,0.3\n0.01,0,0,1.0")
    assert p.layout.acc == [1, 2, 3] and p.layout.gyro == [4, 5, 6]
    assert b.text == ["0.00,0,0,1,0.1,0.2,0.3"]
    # The partial line waits for its rest; a short line, a word and a NaN are garbled.
    b = p.feed(b"1,0.1,0.2,0.3\n0.02,1,2\n0.03,x,0,1,0,0,0\n0.04,nan,0,1,0,0,0\n"
               b"0.05,0.5,0,1,0,0,0\n")
    np.testing.assert_array_equal(b.t, [0.01, 0.05])
    np.testing.assert_array_equal(b.acc, [[0, 0, 1.01], [0.5, 0, 1]])
    np.testing.assert_array_equal(b.gyro[:, 2], [0.3, 0])
    assert b.text == ["0.01,0,0,1.01,0.1,0.2,0.3", "0.05,0.5,0,1,0,0,0"]
    assert p.garbled == 4 and p.valid == 3  # the banner and three bad rows


def test_time_must_move_forward():
    p = LineParser("test")
    b = p.feed(b"t,ax,ay,az\n1,0,0,1\n2,0,0,1\n2,0,0,1\n1.5,0,0,1\n3,0,0,1\n")
    np.testing.assert_array_equal(b.t, [1, 2, 3])
    assert p.garbled == 2


def test_loader_names_and_time_units():
    p = LineParser("test")
    b = p.feed(b"Timestamp (ms);Acc_X;Acc_Y;Acc_Z;Gyr_X;Gyr_Y;Gyr_Z\n"
               b"1000;0;0;9.8;0;0;0\n1010;0;0;9.8;0;0;0\n1020;0;0;9.8;0;0;0\n")
    np.testing.assert_allclose(b.t, [1.0, 1.01, 1.02])
    assert b.text[0] == "1000,0,0,9.8,0,0,0"  # the session file is comma-separated
    # A time without a unit is read as the loader reads it: ms when seconds would be > 1 s apart
    p = LineParser("test")
    b = p.feed(b"timestamp,ax,ay,az\n" + b"".join(b"%d,0,0,1\n" % (5 * i) for i in range(5)))
    np.testing.assert_allclose(np.diff(b.t), 0.005)


def test_columns_for_a_device_without_header_and_rate_numbering():
    p = LineParser("test", columns="ax,ay,az,gx,gy,gz", rate=50.0)
    assert p.header == ["t", "ax", "ay", "az", "gx", "gy", "gz"]
    b = p.feed(b"0 0 1 0 0 0\n0.1  0 1 0 0 0\n")
    b2 = p.feed(b"0.2 0 1 0 0 0\n")
    np.testing.assert_array_equal(np.r_[b.t, b2.t], [0.0, 0.02, 0.04])
    assert b.text == ["0.0,0,0,1,0,0,0", "0.02,0.1,0,1,0,0,0"]
    with pytest.raises(ImucalError, match="--rate"):
        LineParser("test", columns="ax,ay,az")


def test_numbers_without_header_say_columns():
    p = LineParser("serial:/dev/x?baud=9600")
    assert p.feed(b"1,2,3\n4,5,6\n") is None
    assert p.valid == 0 and "--columns" in p.said() and "12 bytes" in p.said()


def test_motioncal_raw_lines():
    p = LineParser("serial:/dev/ttyACM0?baud=115200", rate=100.0)
    b = p.feed(b"hello\nRaw:10,-20,8192,16,0,-32,300,-12,450\nUni:0.1,0,9.8,0,0,0,3,1,4\r\n"
               b"Raw:11,-21,8190,15,1,-33,301,-11,451\n")
    assert p.header[:2] == ["t", "ax (counts)"] and len(p.header) == 10
    np.testing.assert_array_equal(b.t, [0.0, 0.01])
    np.testing.assert_array_equal(b.acc, [[10, -20, 8192], [11, -21, 8190]])
    np.testing.assert_array_equal(b.gyro[:, 2], [-32, -33])
    assert b.text[0] == "0.0,10,-20,8192,16,0,-32,300,-12,450"
    assert p.garbled == 2  # the banner before the first MotionCal line, and the Uni: line
    with pytest.raises(ImucalError, match="--rate"):
        LineParser("x").feed(b"Uni:0.1,0,9.8,0,0,0,3,1,4\n")
