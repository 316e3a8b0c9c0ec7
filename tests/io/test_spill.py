"""A long recording's signals mapped from a temporary file (imucal/io/spill.py, issue 12): the
same values and the same calibration as in memory, nothing left on disk, a bounded resident set,
and a clear error when the folder cannot hold them."""

from __future__ import annotations

import gc
import json
import mmap
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import imucal
from imucal.errors import ImucalError
from imucal.io.calibration_file import result_to_dict
from imucal.io.spill import IN_MEMORY, Spill, SpillPolicy, contiguous, elementwise
from imucal.report import report as build_report

SAMPLE = Path(__file__).resolve().parents[2] / "sample_data" / "session.mat"


def _mapped(a: np.ndarray) -> bool:
    base = a
    while isinstance(base, np.ndarray):
        base = base.base
    if isinstance(base, memoryview):
        base = base.obj
    return isinstance(base, mmap.mmap)


def _spill_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name == "imucal-spill" and t.is_alive()]


def _strip(d: dict) -> dict:
    """Everything but the clock's readings."""
    return {k: v for k, v in d.items() if k not in ("created", "elapsed_s", "software")}


def test_mapped_session_is_the_same_to_the_bit_and_calibrates_the_same(tmp_path):
    mem = imucal.load_session(SAMPLE, spill=IN_MEMORY)
    mapped = imucal.load_session(SAMPLE, spill=SpillPolicy(directory=tmp_path, above_bytes=0))
    assert mem.storage is None and not _mapped(mem.acc)
    for name in ("acc", "t_acc", "gyro", "t_gyro"):
        a, b = getattr(mem, name), getattr(mapped, name)
        assert _mapped(b), name
        assert b.dtype == np.float64 and b.flags.c_contiguous
        assert np.array_equal(a.view(np.int64), b.view(np.int64)), name
    assert list(tmp_path.iterdir()) == []  # unlinked at once: nothing is left behind
    assert mapped.storage is not None and str(tmp_path) in mapped.storage
    r_mem, r_map = imucal.calibrate(mem), imucal.calibrate(mapped)
    d_mem, d_map = _strip(result_to_dict(r_mem)), _strip(result_to_dict(r_map))
    assert json.dumps(d_mem, default=str) == json.dumps(d_map, default=str)
    lines = {line.label: line.text for line in build_report(r_map).overview}
    assert "mapped from a temporary file" in lines["memory"]
    assert "memory" not in {line.label for line in build_report(r_mem).overview}


def test_small_arrays_stay_in_memory_by_default():
    s = imucal.load_session(SAMPLE)
    assert s.storage is None and not _mapped(s.acc)


def test_watcher_ends_when_the_arrays_are_freed(tmp_path):
    spill = Spill(SpillPolicy(directory=tmp_path, above_bytes=0, resident_budget_bytes=0))
    a = spill.empty((1000, 3))
    a[:] = 1.0
    time.sleep(0.1)  # over budget (0): the watcher drops the pages; the data stay
    assert _spill_threads()
    assert a.sum() == 3000.0
    del a, spill
    gc.collect()
    deadline = time.monotonic() + 5
    while _spill_threads() and time.monotonic() < deadline:
        time.sleep(0.02)
    assert not _spill_threads()


RSS_SCRIPT = textwrap.dedent("""
    import sys, time
    from pathlib import Path
    import numpy as np
    from imucal.io.spill import Spill, SpillPolicy
    def rss():
        with open("/proc/self/status") as fh:
            return next(int(x.split()[1]) * 1024 for x in fh if x.startswith("VmRSS"))
    spill = Spill(SpillPolicy(directory=Path(sys.argv[1]), above_bytes=0,
                              resident_budget_bytes=int(sys.argv[2])))
    base = rss()
    a = spill.empty((12_500_000, 3))  # 300 MB
    for lo in range(0, len(a), 1 << 16):
        a[lo:lo + (1 << 16)] = lo
    time.sleep(0.3)  # the watcher looks every 20 ms
    after = rss()
    total = sum(float(a[lo:lo + (1 << 16), 0].sum()) for lo in range(0, len(a), 1 << 16))
    print(base, after, total)  # bytes resident before and after writing, and the data's sum
""")


def _resident(tmp_path: Path, budget: int) -> tuple[int, int, float]:
    out = subprocess.run([sys.executable, "-c", RSS_SCRIPT, str(tmp_path), str(budget)],
                         capture_output=True, text=True, check=True).stdout.split()
    return int(out[0]), int(out[1]), float(out[2])


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the watcher trims on Linux")
def test_mapped_pages_are_dropped_above_the_budget_and_the_data_survive(tmp_path):
    expected = float(sum(lo * min(1 << 16, 12_500_000 - lo) for lo in range(0, 12_500_000,
                                                                           1 << 16)))
    base, after, total = _resident(tmp_path, 1)  # any mapped page is over budget: dropped
    assert total == expected  # read back from the page cache after the drops
    assert after - base < 50e6, (base, after)
    base, after, total = _resident(tmp_path, 1 << 40)  # never over budget: every page stays
    assert total == expected
    assert after - base > 290e6, (base, after)


def test_a_full_disk_is_one_clear_error(tmp_path, monkeypatch):
    import errno
    import os

    def full(fd, offset, length):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "posix_fallocate", full)
    with pytest.raises(ImucalError) as e:
        imucal.load_session(SAMPLE, spill=SpillPolicy(directory=tmp_path, above_bytes=0))
    msg = str(e.value)
    assert e.value.field == "spill" and str(tmp_path) in msg and "space" in msg.lower()
    assert "\n" not in msg and list(tmp_path.iterdir()) == []


def test_a_missing_folder_is_one_clear_error(tmp_path):
    with pytest.raises(ImucalError) as e:
        imucal.load_session(SAMPLE, spill=SpillPolicy(directory=tmp_path / "no", above_bytes=0))
    assert e.value.field == "spill" and "no" in str(e.value)


def test_chunked_steps_equal_numpy_whole(tmp_path):
    rng = np.random.default_rng(3)
    x = rng.standard_normal((200_003, 3)) * 1e3
    spill = Spill(SpillPolicy(directory=tmp_path, above_bytes=0))
    got = elementwise(np.deg2rad, x, spill.empty)
    assert _mapped(got) and np.array_equal(got, np.deg2rad(x))
    f = np.asfortranarray(x)
    got = contiguous(f, spill)
    assert got.flags.c_contiguous and np.array_equal(got, x)
    assert contiguous(got, spill) is got


def test_deg_per_s_gyroscope_is_converted_the_same_when_mapped(tmp_path):
    from scipy.io import savemat

    s = imucal.load_session(SAMPLE, spill=IN_MEMORY)
    path = tmp_path / "deg.mat"
    savemat(path, {"acc": s.acc, "gyro": np.rad2deg(s.gyro), "t": s.t_acc})
    spill_dir = tmp_path / "spill"
    spill_dir.mkdir()
    mem = imucal.load_session(path, gyro_unit="deg/s", spill=IN_MEMORY)
    mapped = imucal.load_session(path, gyro_unit="deg/s",
                                 spill=SpillPolicy(directory=spill_dir, above_bytes=0))
    assert _mapped(mapped.gyro)
    assert np.array_equal(mem.gyro, mapped.gyro)
