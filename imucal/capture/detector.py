"""The still detector of a live capture: M1 (method.md §1) one batch of samples at a time, the
holds it makes, the poses they reach and the pose to hold next (method.md §13).

``s2 = var_x^2 + var_y^2 + var_z^2`` over the ``window`` samples that end at each sample (a
trailing window: the live answer cannot wait for samples to come), from running sums over the
batch and the previous ``window - 1`` samples, on data centred on the first sample (float64, no
cancellation): O(window + batch) per batch, constant memory. A sample is still where
``s2 < K * s2_floor``, ``s2_floor`` being the quietest second so far (the median of M1 over each
second of samples, the least of them): the batch method's ``s2_init`` without assuming that the
device starts still. Runs of still samples ``MIN_HOLD_S`` long are holds; each hold's mean vector
is the direction that was up (the accelerometer reads +|g| along it).

This detector guides the user and decides when to try a calibration; the calibration itself
runs the full method, its own detector included, on the session file.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from imucal.numerics.directions import distinct_orientations
from imucal.numerics.windows import runs_of_true
from imucal.stages.accel_cv import axis_words, coverage
from imucal.stages.guide import ADVISED_HOLD_S, ORIENTATIONS_NEEDED, suggest_poses

WINDOW_S = 0.25  # the batch method's shortest window (method.md §1): a hold is seen soon
MIN_HOLD_S = 1.5  # a still run this long is a hold (the shortest that makes a block, 1-2 s)
K = 16.0  # s2 below K times the floor is still: each axis's noise up to twice the quietest
RATE_SAMPLES = 32  # samples whose median step gives the rate (and so the window)


@dataclass(frozen=True)
class Hold:
    start: float  # s, first still sample (its window's end)
    end: float  # s
    mean: np.ndarray  # (3,) mean raw acceleration: the axis that was up


@dataclass
class DetectorState:
    """What the guide says after a batch."""

    state: str  # "waiting" (no rate or floor yet), "still" or "moving"
    hold_s: float  # how long the current still run has lasted (0 when moving)
    holds: int
    orientations: int
    coverage: float  # fraction of the sphere within 45 degrees of a pose
    next_pose: str  # the axis to point up next, in words
    new_holds: list[Hold] = field(default_factory=list)  # the holds this batch completed
    up: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (H, 3) each hold's
    #   unit direction that was up, about the centre (see centred)
    gravity: np.ndarray | None = None  # (3,) the last sample's unit direction, same centre
    next_up: np.ndarray | None = None  # (3,) the pose advised next, a unit direction


class StillDetector:
    def __init__(self) -> None:
        self.rate: float | None = None
        self.window = 0
        self.first: list[np.ndarray] = []  # (t, acc) kept only until the rate is known
        self.ref: np.ndarray | None = None
        self.tail = np.zeros((0, 3))  # the last window - 1 centred samples
        self.t_last = -np.inf
        self.second: list[np.ndarray] = []  # M1 values of the second being measured
        self.second_n = 0
        self.floor = np.inf
        self.run_start: float | None = None  # time the current still run began
        self.run_sum = np.zeros(3)
        self.run_n = 0
        self.holds: list[Hold] = []
        self.orientations = 0
        self.covered = 0.0
        self.next_pose = "any axis up"
        self.centre = np.zeros(3)  # the zero the holds' means are taken about
        self.up = np.zeros((0, 3))
        self.next_up: np.ndarray | None = None
        self.last = np.zeros(3)  # the last sample's raw acceleration

    def feed(self, t: np.ndarray, acc: np.ndarray) -> DetectorState:
        """Take a batch (times in s, raw acceleration (N, 3)); the guide after it."""
        if self.rate is None:
            self.first.append(np.column_stack([t, acc]))
            rows = np.vstack(self.first)
            if len(rows) < RATE_SAMPLES:
                return self._state(False)
            self.first = []
            self.rate = 1.0 / float(np.median(np.diff(rows[:, 0])))
            self.window = max(5, round(WINDOW_S * self.rate))
            self.ref = rows[0, 1:].copy()
            t, acc = rows[:, 0], rows[:, 1:]
        x = np.vstack([self.tail, np.asarray(acc, dtype=np.float64) - self.ref])
        w, n_tail = self.window, len(self.tail)
        s1 = np.vstack([np.zeros((1, 3)), np.cumsum(x, axis=0)])
        s2 = np.vstack([np.zeros((1, 3)), np.cumsum(x * x, axis=0)])
        end = np.arange(n_tail, len(x)) + 1  # each new sample's window is [end - w, end)
        ok = end >= w
        lo = np.maximum(end - w, 0)
        mean = (s1[end] - s1[lo]) / w
        var = (s2[end] - s2[lo]) / w - mean * mean
        m1 = np.where(ok, (var * var).sum(axis=1), np.inf)  # M1
        self.tail = x[-(w - 1):] if w > 1 else x[:0]
        self._update_floor(m1[ok])
        still = m1 < K * self.floor
        new = self._runs(np.asarray(t, dtype=np.float64), np.asarray(acc, dtype=np.float64),
                         still)
        if new:
            self._poses()
        self.last = np.asarray(acc[-1], dtype=np.float64)
        st = self._state(bool(still[-1]))
        st.new_holds = new
        return st

    def _update_floor(self, m1: np.ndarray) -> None:
        """The quietest second so far: M1's median over each ``rate`` values."""
        per = max(int(self.rate), self.window)
        while len(m1):
            take = m1[: per - self.second_n]
            self.second.append(take)
            self.second_n += len(take)
            m1 = m1[len(take):]
            if self.second_n >= per:
                self.floor = min(self.floor, float(np.median(np.concatenate(self.second))))
                self.second, self.second_n = [], 0

    def _runs(self, t: np.ndarray, acc: np.ndarray, still: np.ndarray) -> list[Hold]:
        """Extend or close the current still run and every run in the batch (a loop over the
        runs, a few per batch, not over the samples)."""
        new = []
        runs = runs_of_true(still)
        for a, b in runs:
            if a > 0 or self.run_start is None:  # a run that starts here
                self._close(new)
                self.run_start, self.run_sum, self.run_n = float(t[a]), np.zeros(3), 0
            self.run_sum += acc[a:b].sum(axis=0)
            self.run_n += b - a
            self.t_last = float(t[b - 1])
            if b < len(still):  # it ends inside the batch
                self._close(new)
        if not len(runs):
            self._close(new)
        return new

    def _close(self, new: list[Hold]) -> None:
        if self.run_start is not None and self.t_last - self.run_start >= MIN_HOLD_S:
            hold = Hold(self.run_start, self.t_last, self.run_sum / self.run_n)
            self.holds.append(hold)
            new.append(hold)
        self.run_start, self.run_n = None, 0

    def _poses(self) -> None:
        means = np.array([h.mean for h in self.holds])
        up = centred(means)
        self.centre = means[0] - up[0]
        self.up = up / np.linalg.norm(up, axis=1, keepdims=True)
        self.orientations = distinct_orientations(up)
        missing, self.covered = coverage(up)
        suggested = suggest_poses(missing, limit=1)
        self.next_up = suggested[0] if len(suggested) else None
        self.next_pose = (f"{axis_words(suggested[0])} up" if len(suggested)
                          else "any new pose (the sphere is covered)")

    def _state(self, still: bool) -> DetectorState:
        if self.rate is None or not np.isfinite(self.floor):
            state, hold = "waiting", 0.0
        elif still and self.run_start is not None:
            state, hold = "still", self.t_last - self.run_start
        else:
            state, hold = "moving", 0.0
        g = self.last - self.centre
        norm = float(np.linalg.norm(g))
        return DetectorState(state=state, hold_s=hold, holds=len(self.holds),
                             orientations=self.orientations, coverage=self.covered,
                             next_pose=self.next_pose, up=self.up,
                             gravity=g / norm if norm > 0 else None, next_up=self.next_up)


def centred(means: np.ndarray) -> np.ndarray:
    """The holds' means about the sphere they lie on, where they determine one.

    Raw counts sit on a sphere whose centre is the zero offset (32768 counts for many ADCs):
    about the origin every pose would point the same way. The centre is the least-squares
    sphere through the means (``|m - c|^2 = r^2``, linear in ``c`` and ``r^2 - |c|^2``), taken
    only when the means determine it (a well-conditioned system) and lie on it (radii within
    5 %); otherwise the means are taken as they are (a sensor in g or m/s^2, whose offset is
    small beside |g|)."""
    if len(means) < 5:
        return means
    m0 = means.mean(axis=0)
    spread = float(np.abs(means - m0).max())
    if spread == 0.0:
        return means
    x = (means - m0) / spread
    a = np.column_stack([2 * x, np.ones(len(x))])
    if np.linalg.cond(a) > 30:
        return means
    sol = np.linalg.lstsq(a, (x * x).sum(axis=1), rcond=None)[0]
    radii = np.linalg.norm(x - sol[:3], axis=1)
    if radii.std() > 0.05 * radii.mean():
        return means
    return means - (m0 + spread * sol[:3])


def guide_line(st: DetectorState) -> str:
    """The guide in words, for the terminal."""
    need = max(ORIENTATIONS_NEEDED - st.orientations, 0)
    if st.state == "waiting":
        return "waiting: keep the device still while the noise is measured"
    if st.state == "still":
        return (f"still {st.hold_s:4.1f} s (a hold counts from {MIN_HOLD_S:g} s, "
                f"{ADVISED_HOLD_S:g} s advised); {st.orientations} poses")
    more = f", {need} more needed" if need else ""
    return f"moving; {st.orientations} poses{more}: next hold with {st.next_pose}"
