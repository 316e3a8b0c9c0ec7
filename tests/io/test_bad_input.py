"""Every bad input of the robustness issue, through the command line: exit 1, one line that
names the file and the problem, and no output file."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.io

IMUCAL = str(Path(sys.executable).parent / "imucal")


def _good(n: int = 2000) -> np.ndarray:
    t = np.arange(n) / 100.0
    rng = np.random.default_rng(0)
    return np.column_stack([t, rng.normal(0, 0.01, (n, 3)) + [0, 0, 1], rng.normal(0, 0.01,
                                                                                  (n, 3))])


def _csv(path: Path, m: np.ndarray, header: str = "t,ax,ay,az,gx,gy,gz") -> Path:
    lines = [header] + [",".join(f"{v:.6f}" for v in row) for row in m]
    path.write_text("\n".join(lines) + "\n")
    return path


def missing(d):
    return d / "nope.csv", [], "not found"


def empty(d):
    p = d / "empty.csv"
    p.write_bytes(b"")
    return p, [], "empty"


def png_renamed(d):
    p = d / "picture.mat"
    p.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 4)
    return p, [], "format"


def truncated_mat(d):
    p = d / "cut.mat"
    m = _good()
    scipy.io.savemat(p, {"acc": m[:, 1:4], "gyro": m[:, 4:], "t": m[:, 0]})
    p.write_bytes(p.read_bytes()[:600])
    return p, [], "cut.mat"


def mat_without_numbers(d):
    p = d / "text.mat"
    scipy.io.savemat(p, {"name": "not a signal"})
    return p, [], "numeric"


def text_in_column(d):
    p = _csv(d / "text.csv", _good())
    lines = p.read_text().splitlines()
    lines[50] = lines[50].replace(lines[50].split(",")[2], "abc", 1)
    p.write_text("\n".join(lines) + "\n")
    return p, [], "abc"


def ragged(d):
    p = _csv(d / "ragged.csv", _good())
    lines = p.read_text().splitlines()
    lines[30] = lines[30] + ",1.0"
    p.write_text("\n".join(lines) + "\n")
    return p, [], "line"


def five_columns(d):
    p = d / "five.txt"
    np.savetxt(p, _good()[:, 1:6])
    return p, ["--rate", "100"], "found 5 column"


def three_columns_no_gyro(d):
    p = d / "three.txt"
    np.savetxt(p, _good()[:, 1:4])
    return p, ["--rate", "100"], "no gyroscope"


def unknown_column(d):
    p = _csv(d / "cols.csv", _good())
    return p, ["--columns", "ax=nosuch"], "nosuch"


def nan_run(d):
    m = _good()
    m[500:600, 2] = np.nan
    return _csv(d / "nan.csv", m), [], "NaN"


def time_backwards(d):
    m = _good()
    m[700, 0] = m[600, 0]
    return _csv(d / "back.csv", m), [], "increasing"


def time_duplicated(d):
    m = _good()
    m[700, 0] = m[699, 0]
    return _csv(d / "dup.csv", m), [], "increasing"


def rate_zero(d):
    p = d / "norate.txt"
    np.savetxt(p, _good()[:, 1:])
    return p, ["--rate", "0"], "rate"  # an option's value: a usage error, exit 2


def rate_absurd(d):
    p = d / "fast.txt"
    np.savetxt(p, _good()[:, 1:])
    return p, ["--rate", "1e9"], "rate"


def no_rate(d):
    p = d / "notime.txt"
    np.savetxt(p, _good()[:, 1:])
    return p, [], "rate"


CASES = [missing, empty, png_renamed, truncated_mat, mat_without_numbers, text_in_column, ragged,
         five_columns, three_columns_no_gyro, unknown_column, nan_run, time_backwards,
         time_duplicated, rate_zero, rate_absurd, no_rate]


@pytest.mark.parametrize("case", CASES, ids=[c.__name__ for c in CASES])
def test_bad_input_is_refused_in_one_line(tmp_path, case):
    path, extra, word = case(tmp_path)
    out = tmp_path / "calib.json"
    proc = subprocess.run([IMUCAL, "calibrate", str(path), "--out", str(out), *extra],
                          capture_output=True, text=True, timeout=120)
    expected = 2 if case is rate_zero else 1
    assert proc.returncode == expected, (proc.returncode, proc.stderr)
    lines = proc.stderr.strip().splitlines()
    if expected == 2:  # click's usage block: the reason is its last line
        lines = lines[-1:]
        assert "--rate" in lines[0] and "positive" in lines[0]
        return
    assert len(lines) == 1, proc.stderr
    assert path.name in lines[0] and word.lower() in lines[0].lower(), lines[0]
    assert "Traceback" not in proc.stderr
    assert not out.exists()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_output_equal_to_input_is_refused(tmp_path):
    p = _csv(tmp_path / "s.csv", _good())
    before = p.read_bytes()
    proc = subprocess.run([IMUCAL, "calibrate", str(p), "--out", str(p)], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 1 and "s.csv" in proc.stderr and "input" in proc.stderr
    assert p.read_bytes() == before


def test_output_directory_must_exist(tmp_path):
    p = _csv(tmp_path / "s.csv", _good())
    out = tmp_path / "no" / "such" / "calib.json"
    proc = subprocess.run([IMUCAL, "calibrate", str(p), "--out", str(out)], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 1 and "does not exist" in proc.stderr
    assert not out.parent.exists()
