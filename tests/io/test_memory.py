"""Loading a MATLAB v5 session costs the session and little more (issue 12: a worker's memory is
bounded by the session): the variables are read straight into the arrays the Session keeps,
bit for bit what scipy reads, and one time array serves both sensors when they share it.

Allocations are measured with tracemalloc (numpy reports its buffers to it), not timed."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest
from scipy.io import savemat

from imucal.io.load import load_session
from imucal.io.load_mat5 import read_mat5_arrays
from imucal.io.readers import _read_mat5_general

N = 200_000  # 200 s at 1 kHz: 11 MB of session, far above numpy's and Python's small change


def _session_file(path, *, compressed: bool, rows: bool, shared_time: bool) -> None:
    rng = np.random.default_rng(7)
    t = np.arange(N) / 1000.0
    g = rng.normal(0.0, 0.003, (N, 3)) + [0.0, 0.0, 1.0]
    w = rng.normal(0.0, 0.003, (N, 3))
    data = {"acc": g if rows else g.T, "gyro": w if rows else w.T, "t_acc": t[:, None],
            "label": "unit 7", "meta": {"rate": 1000.0}, "flag": np.array([[True]]),
            "counts": np.arange(6, dtype=np.int16).reshape(2, 3), "empty": np.zeros((0, 3))}
    data["t_gyro"] = t[:, None].copy() if shared_time else t[:, None] + 1e-4
    savemat(path, data, do_compression=compressed)


@pytest.mark.parametrize("compressed", [False, True])
@pytest.mark.parametrize("rows", [False, True])
def test_mat5_reader_reads_what_scipy_reads(tmp_path, compressed, rows) -> None:
    path = tmp_path / "s.mat"
    _session_file(path, compressed=compressed, rows=rows, shared_time=True)
    mine, general = read_mat5_arrays(path), _read_mat5_general(path).arrays
    assert sorted(mine) == sorted(general) == ["acc", "counts", "flag", "gyro", "t_acc",
                                               "t_gyro"]
    for name, arr in general.items():
        assert mine[name].dtype == np.float64 and mine[name].shape == arr.shape, name
        assert np.array_equal(mine[name].view(np.int64), arr.view(np.int64)), name
    # Samples along rows come out C-ordered, as the Session keeps them: no copy on the way.
    oriented = mine["acc"] if rows else mine["acc"].T
    assert oriented.flags.c_contiguous


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("compressed", [False, True])
def test_loading_costs_the_session_and_little_more(tmp_path, compressed, threads) -> None:
    path = tmp_path / "s.mat"
    _session_file(path, compressed=compressed, rows=True, shared_time=True)
    tracemalloc.start()
    try:
        session = load_session(path, threads=threads)
        held, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert session.t_gyro is session.t_acc  # equal bit for bit: one array
    size = session.acc.nbytes + session.gyro.nbytes + session.t_acc.nbytes  # 11.2 MB
    assert size <= held < 1.05 * size
    # scipy's path peaked at 2.1x the session (the file, its inflated copy and scipy's arrays);
    # now the largest extra is the gyroscope's |w| for its unit guess (half the session here).
    # With threads the file's hash runs beside the reading: its chunks (1 MiB, one alive and
    # one being let go) may fall on the reading's peak or not, a constant, not the session's.
    hashing = 0 if threads == 1 else 2 << 20
    assert peak < 1.55 * size + hashing, (peak / size)  # 1.43 measured in one thread


def test_different_time_arrays_stay_apart(tmp_path) -> None:
    path = tmp_path / "s.mat"
    _session_file(path, compressed=True, rows=True, shared_time=False)
    session = load_session(path)
    assert session.t_gyro is not session.t_acc
    assert session.t_gyro[0] == 1e-4 and session.t_acc[0] == 0.0


def test_unit_guesses_are_numpys_order_statistics_without_a_copy() -> None:
    """The gyroscope's median and 99.5th percentile of |w| and the accelerometer's median
    norm, found in blocks of rows from a bracket: numpy's values to the bit (ties, heavy
    tails, odd and even counts), allocating far less than the (N, 3) copy they replace."""
    from imucal.io.units import _median_row_norm, abs_median_p995

    rng = np.random.default_rng(5)
    for n, kind in [(5 * N, "normal"), (5 * N + 1, "ties"), (5 * N - 1, "tails")]:
        x = rng.normal(0.0, 1.0, (n, 3))
        if kind == "ties":
            x = np.round(x * 4)
        elif kind == "tails":
            x = rng.standard_t(2, (n, 3))
        magnitude = np.abs(x)
        want = (float(np.median(magnitude)), float(np.percentile(magnitude, 99.5)))
        del magnitude
        tracemalloc.start()
        try:
            got = abs_median_p995(x, small=0)
            _, peak = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
        assert got == want, kind
        # The copy was 1.0x; ties keep every value equal to a bracket's edge (one level of 4
        # per unit here holds ~10 % of the values).
        assert peak < (0.5 if kind == "ties" else 0.25) * x.nbytes, (kind, peak / x.nbytes)
        assert _median_row_norm(x, small=0) == float(np.median(np.linalg.norm(x, axis=1)))
