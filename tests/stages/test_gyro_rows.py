"""The gyroscope stage reads the session's arrays as an array kept on disk can be read (issue
12): ``len``, ``.shape``, ``.ndim``, ``.dtype``, slices of rows and gathers with a 1-D integer
array, never the whole array; and it finds the same calibration, to the bit, as from the
ndarrays themselves."""

from __future__ import annotations

import numpy as np
import pytest

from imucal.numerics.rk4 import intervals
from imucal.stages.gyro import calibrate_gyroscope
from imucal.stages.gyro_transitions import sorted_position
from imucal.synth import make_session


class RowsOnly:
    """An array that offers only what a disk-backed session array offers (and counts what is
    read); anything else, ``np.asarray`` among them, raises."""

    def __init__(self, a: np.ndarray):
        self._a = a
        self.shape, self.ndim, self.dtype = a.shape, a.ndim, a.dtype
        self.rows_read = 0
        self.largest = 0  # rows of the largest read

    def __len__(self) -> int:
        return len(self._a)

    def __getitem__(self, key):
        rows = key[0] if isinstance(key, tuple) and len(key) == 2 else key
        if isinstance(key, tuple) and not isinstance(key[1], int | np.integer):
            raise TypeError(f"only a column of a slice of rows: {key!r}")
        if isinstance(rows, slice) and rows.step in (None, 1):
            out = np.array(self._a[key])  # a fresh C-order copy
            if len(out) == len(self._a):
                raise AssertionError("a slice of every row is reading the whole array")
        elif (isinstance(key, np.ndarray) and key.ndim == 1 and key.dtype.kind in "iu"):
            out = self._a[key]
        else:
            raise TypeError(f"not a read of rows: {key!r}")
        self.rows_read += len(out)
        self.largest = max(self.largest, len(out))
        return out

    def __array__(self, *args, **kwargs):
        raise TypeError("the whole array was asked for")

    def __iter__(self):
        raise TypeError("the array was iterated")


def _fit(session, truth, w, t):
    lo, hi = (np.searchsorted(session.t_acc, truth.pose_times[:, i] + d) for i, d in
              ((0, 0.2), (1, -0.2)))
    acc = truth.acc.apply(session.acc)
    gravity = np.array([acc[a:b].mean(axis=0) for a, b in zip(lo, hi)])
    return calibrate_gyroscope(w, t, truth.pose_times + [0.2, -0.2], gravity,
                               session.gyro_unit)


@pytest.mark.parametrize("unit", ["rad/s", "counts"])
def test_a_disk_backed_session_gives_the_same_calibration_to_the_bit(unit, monkeypatch):
    # 2 kHz: each turn some 4000 steps, gathered two or three turns at a time (and counts go
    # through the scale search too)
    session, truth = make_session(poses=12, seed=4, gyro_rate=2000.0, gyro_unit=unit)
    want = _fit(session, truth, session.gyro, session.t_gyro)
    monkeypatch.setattr(intervals, "CHUNK_ROWS", 10_000)
    w, t = RowsOnly(session.gyro), RowsOnly(session.t_gyro)
    got = _fit(session, truth, w, t)
    for a, b in [(got.model.T, want.model.T), (got.model.K, want.model.K),
                 (got.model.b, want.model.b), (got.std, want.std),
                 (got.u_pred_after, want.u_pred_after), (got.cv.angle, want.cv.angle),
                 (got.report.jac, want.report.jac), (got.t_transition, want.t_transition)]:
        np.testing.assert_array_equal(a, b)
    assert got.nominal_scale == want.nominal_scale
    # and it was read: the turns many times over, a chunk of turns at a time
    assert w.rows_read > len(session.gyro) and t.rows_read > len(session.t_gyro)
    assert 4000 < w.largest <= 10_000


def test_sorted_positions_by_gathers_are_searchsorteds():
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.5, 1.5, 1000))
    v = np.r_[rng.uniform(t[0] - 5, t[-1] + 5, 200), t[::7], t[0] - 1, t[-1] + 1]
    for side in ("left", "right"):
        np.testing.assert_array_equal(sorted_position(RowsOnly(t), v, side),
                                      np.searchsorted(t, v, side))
    assert len(sorted_position(t, np.zeros(0))) == 0
