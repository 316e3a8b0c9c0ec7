"""imucal.numerics.rk4.intervals: the samples read in place (any layout) or gathered a chunk of
intervals at a time from an array that offers only gathers of rows give the same numbers to the
bit; integrate_transitions on the edge cases."""

import subprocess
import sys

import numpy as np
import pytest
from row_only import RowOnly

from imucal.numerics.rk4 import Intervals, integrate_transitions
from imucal.numerics.rk4 import intervals as intervals_module
from imucal.numerics.rk4.intervals import chunks


def _recording(n=3000, seed=0):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.008, 0.012, n))
    return t, rng.normal(0, 1.0, (n, 3)) + [0.01, -0.02, 0.03]


STARTS = np.array([0, 100, 590, 300, 1000, 2990, 1500])
ENDS = np.array([50, 103, 1599, 300, 2500, 2999, 1500])


def _passes(iv: Intervals) -> dict:
    rng = np.random.default_rng(1)
    M, b = np.eye(3) + 0.05 * rng.normal(size=(3, 3, 3)), 0.02 * rng.normal(size=(3, 3))
    Me, be = np.eye(3) + 0.05 * rng.normal(size=(len(iv), 3, 3)), rng.normal(size=(len(iv), 3))
    q, S = iv.sensitivity(M[0], b[0])
    return {"integrate": iv.integrate(M, b), "each": iv.integrate_each(Me, be), "q": q,
            "S": S, "max_step": iv.max_step(M[1], b[1]), "raw_turn": iv.raw_turn(b[2])}


def _same(a: dict, b: dict) -> None:
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)


@pytest.mark.parametrize("chunk_rows", [10, 1200, 1 << 16])
def test_gathered_in_chunks_the_numbers_are_the_same_to_the_bit(monkeypatch, chunk_rows):
    t, w = _recording()
    whole = Intervals(w, t, STARTS, ENDS)
    assert whole.in_place
    monkeypatch.setattr(intervals_module, "CHUNK_ROWS", chunk_rows)
    x, tt = RowOnly(w), RowOnly(t)
    rows = Intervals(x, tt, STARTS, ENDS)
    assert not rows.in_place and len(rows.chunks) == {10: 7, 1200: 3, 1 << 16: 1}[chunk_rows]
    _same(_passes(rows), _passes(whole))
    # a chunk of whole intervals at a time (the longest, 1501 rows, alone when the chunk is
    # smaller)
    lengths = ENDS - STARTS + 1
    assert x.largest == max(lengths[k0:k1].sum() for k0, k1 in rows.chunks)
    assert x.largest <= max(chunk_rows, 1501) and tt.largest == x.largest


def test_any_layout_or_dtype_gives_the_same_numbers():
    t, w = _recording(seed=2)
    want = _passes(Intervals(w, t, STARTS, ENDS))
    wide = np.zeros((len(w), 7))
    wide[:, 2:5] = w
    readonly = w.copy()
    readonly.flags.writeable = False
    for x, in_place in [(np.asfortranarray(w), True), (wide[:, 2:5], True), (readonly, False),
                        (w.astype(np.float32).astype(np.float64), True)]:
        iv = Intervals(x, t, STARTS, ENDS)
        assert iv.in_place == in_place
        got = _passes(iv)
        if x.dtype == w.dtype and np.array_equal(x, w):
            _same(got, want)
    # samples of another dtype are gathered (as float64, exactly)
    w32 = w.astype(np.float32)
    iv = Intervals(w32, t, STARTS, ENDS)
    assert not iv.in_place
    _same(_passes(iv), _passes(Intervals(w32.astype(np.float64), t, STARTS, ENDS)))


def test_no_intervals():
    t, w = _recording(seed=3)
    for x in (w, RowOnly(w)):
        iv = Intervals(x, t, np.zeros(0, int), np.zeros(0, int))
        got = _passes(iv)
        assert got["integrate"].shape == (3, 0, 4) and got["S"].shape == (0, 3, 3, 4)
        assert got["max_step"] == 0.0 and got["raw_turn"].shape == (0,)


def test_chunks_hold_whole_intervals_up_to_the_rows():
    assert chunks(np.array([3, 4, 10, 1, 1, 1]), 7) == [(0, 2), (2, 3), (3, 6)]
    assert chunks(np.array([8]), 7) == [(0, 1)] and chunks(np.zeros(0, int), 7) == []


def test_integrate_transitions_of_nothing_and_of_no_steps():
    t, w = _recording(seed=2)
    assert integrate_transitions(w, t, np.zeros(0, int), np.zeros(0, int)).shape == (0, 4)
    q = integrate_transitions(w, t, np.array([10, 20]), np.array([10, 25]))
    np.testing.assert_array_equal(q[0], [1.0, 0.0, 0.0, 0.0])  # no step: no rotation
    assert abs(q[1, 0]) < 1.0  # five steps of about 1 rad/s: a rotation


def test_integrate_transitions_composes_over_consecutive_intervals():
    # The rotation over [a, c] is the rotation over [a, b] followed by that over [b, c].
    t, w = _recording(seed=3)
    q = integrate_transitions(w, t, np.array([50, 50, 250]), np.array([400, 250, 400]))
    pw, px, py, pz = q[1]
    qw, qx, qy, qz = q[2]
    composed = np.array([pw * qw - px * qx - py * qy - pz * qz,
                         pw * qx + px * qw + py * qz - pz * qy,
                         pw * qy - px * qz + py * qw + pz * qx,
                         pw * qz + px * qy - py * qx + pz * qw])
    np.testing.assert_allclose(q[0] * np.sign(q[0, 0]), composed * np.sign(composed[0]),
                               atol=1e-13)


def test_numba_is_imported_by_the_first_pass_not_by_the_package():
    # ~0.7 s CPU (numba and the kernels' cache): not paid by --help or an accelerometer-only run
    code = ("import sys, numpy as np, imucal.cli, imucal.pipeline\n"
            "from imucal.numerics.rk4 import Intervals\n"
            "iv = Intervals(np.zeros((3, 3)), np.arange(3.0), np.array([0]), np.array([2]))\n"
            "assert 'numba' not in sys.modules\n"
            "iv.raw_turn(np.zeros(3))\n"
            "assert 'numba' in sys.modules\n")
    subprocess.run([sys.executable, "-c", code], check=True)
