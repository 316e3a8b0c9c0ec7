"""The variables of a MAT file inflated in parallel threads: the same arrays, bit for bit, as one
thread reads (and as scipy reads), and the same one-line error, naming the file and the variable,
when a compressed variable is corrupt or cut short (issue 12)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.io import savemat

import imucal.io.load_mat5 as load_mat5
from imucal.errors import ImucalError
from imucal.io.load import load_session
from imucal.io.load_mat5 import read_mat5_arrays
from imucal.io.readers import _read_mat5_general, read_file

N = 60_000


def _file(path, *, compressed: bool = True, rows: bool = True) -> None:
    rng = np.random.default_rng(11)
    t = np.arange(N) / 1000.0
    acc = rng.normal(0.0, 0.003, (N, 3)) + [0.0, 0.0, 1.0]
    gyro = rng.normal(0.0, 0.01, (N, 3))
    counts = np.round(rng.normal(3e4, 40, (N, 3))).astype(np.int16)
    savemat(path, {"acc": acc if rows else acc.T, "gyro": gyro if rows else gyro.T,
                   "t_acc": t[:, None], "t_gyro": t[:, None] + 1e-4, "raw": counts,
                   "label": "unit 7", "u32": np.arange(7, dtype=np.uint32)[:, None]},
            do_compression=compressed)


def _same(a: dict, b: dict, layout: bool = True) -> None:
    assert sorted(a) == sorted(b)
    for name in a:
        assert a[name].dtype == b[name].dtype == np.float64, name
        assert a[name].shape == b[name].shape, name
        assert not layout or a[name].flags.c_contiguous == b[name].flags.c_contiguous, name
        assert np.array_equal(a[name].view(np.int64), b[name].view(np.int64)), name


@pytest.mark.parametrize("compressed", [True, False])
@pytest.mark.parametrize("rows", [True, False])
def test_threads_read_what_one_thread_and_scipy_read(tmp_path, compressed, rows) -> None:
    path = tmp_path / "s.mat"
    _file(path, compressed=compressed, rows=rows)
    one = read_mat5_arrays(path, threads=1)
    _same(one, read_mat5_arrays(path, threads=4))
    _same(one, _read_mat5_general(path).arrays, layout=False)  # scipy's are all F-ordered
    assert sorted(one) == ["acc", "gyro", "raw", "t_acc", "t_gyro", "u32"]


def test_values_split_across_pieces_are_joined(tmp_path, monkeypatch) -> None:
    """Inflated pieces of an odd length split values (8-byte doubles, 2-byte counts) in two."""
    path = tmp_path / "s.mat"
    _file(path)
    want = _read_mat5_general(path).arrays
    monkeypatch.setattr(load_mat5, "_PIECE", 1001)
    monkeypatch.setattr(load_mat5, "_READ", 777)
    for threads in (1, 3):
        _same(want, read_mat5_arrays(path, threads=threads), layout=False)


def test_load_session_is_the_same_in_any_number_of_threads(tmp_path) -> None:
    path = tmp_path / "s.mat"
    _file(path)
    one, two = load_session(path, threads=1), load_session(path, threads=2)
    for a, b in [(one.acc, two.acc), (one.gyro, two.gyro), (one.t_acc, two.t_acc),
                 (one.t_gyro, two.t_gyro)]:
        assert np.array_equal(a.view(np.int64), b.view(np.int64))
    assert one.notes == two.notes


def _compressed_spans(data: bytes) -> list[tuple[int, int]]:
    """(start of the body, its length) of each top-level compressed element."""
    spans, pos = [], 128
    while pos + 8 <= len(data):
        kind, n = np.frombuffer(data[pos:pos + 8], "<u4")
        assert kind == 15
        spans.append((pos + 8, int(n)))
        pos += 8 + int(n)
    return spans


@pytest.mark.parametrize("threads", [1, 4])
def test_a_variable_that_does_not_inflate_is_named(tmp_path, threads) -> None:
    path = tmp_path / "bad.mat"
    savemat(path, {"t_acc": np.arange(N, dtype=float)[:, None],
                   "acc": np.random.default_rng(1).normal(size=(N, 3)),
                   "gyro": np.random.default_rng(2).normal(size=(N, 3))}, do_compression=True)
    data = bytearray(path.read_bytes())
    for body, n in _compressed_spans(bytes(data))[1:]:  # acc and gyro: garbage mid-stream
        data[body + n // 2:body + n // 2 + 64] = bytes(range(64))
    path.write_bytes(bytes(data))
    with pytest.raises(ImucalError) as err:
        read_file(path, threads=threads)
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith("bad.mat: acc: corrupt MATLAB v5 file: the variable does not "
                              "inflate"), message  # the first in the file, in either mode


@pytest.mark.parametrize("threads", [1, 4])
def test_a_variable_cut_short_is_named(tmp_path, threads) -> None:
    path = tmp_path / "cut.mat"
    _file(path)
    data = path.read_bytes()
    body, n = _compressed_spans(data)[1]  # gyro
    path.write_bytes(data[:body + n // 2])
    with pytest.raises(ImucalError) as err:
        load_session(path, threads=threads)
    assert str(err.value) == ("cut.mat: gyro: corrupt MATLAB v5 file: the variable is cut "
                              "short: the file ends inside it")


def test_a_batch_worker_loads_in_one_thread(tmp_path, monkeypatch) -> None:
    """issue 12: workers, not threads, use the cores (imucal.fleet.batch.run_job)."""
    import imucal.io.load as load
    from imucal.fleet.batch import Job, run_job
    from imucal.fleet.naming import identify

    asked = {}

    def spy(path, **kw):
        asked.update(kw)
        raise ImucalError("stop here", source=str(path))

    monkeypatch.setattr(load, "load_session", spy)
    path = tmp_path / "dev" / "s.mat"
    path.parent.mkdir()
    _file(path)
    job = Job(path=str(path), out_dir=str(tmp_path / "out"), name="dev/s",
              identity=identify(path, None), sha256="", settings_hash="", load_kw={},
              settings={})
    row = run_job(job)
    assert row["status"] == "failed" and "stop here" in row["error"]
    assert asked["threads"] == 1
