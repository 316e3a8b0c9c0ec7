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

This detector guides the user and keeps what the running fits need (method.md §13), in
memory that does not grow with the stream: each hold's mean, count and per-axis variance (the
accelerometer's fit, M2-M3, needs no more), its gyroscope sums (the still bias), and the
gyroscope samples of the turns between the latest ``max_turns + 1`` consecutive holds, each turn
in at most :data:`~imucal.capture.turns.MAX_TURN_SAMPLES` rows. At most ``max_blocks`` holds
are kept for the accelerometer: past that, of the two kept holds whose directions are closest,
the one with fewer samples is dropped (its direction stays measured by the other). The final
calibration runs the full method, its own detector included, on the session file.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from imucal.capture.turns import TurnBuffer
from imucal.errors import plural
from imucal.numerics.directions import distinct_orientations
from imucal.numerics.windows import runs_of_true
from imucal.stages.accel_cv import axis_words, coverage
from imucal.stages.guide import ADVISED_HOLD_S, ORIENTATIONS_NEEDED, suggest_poses

WINDOW_S = 0.25  # the batch method's shortest window (method.md §1): a hold is seen soon
MIN_HOLD_S = 1.5  # a still run this long is a hold (the shortest that makes a block, 1-2 s)
K = 16.0  # s2 below K times the floor is still: each axis's noise up to twice the quietest
RATE_SAMPLES = 32  # samples whose median step gives the rate (and so the window)
# What the running fits keep (method.md §13). The presets' targets are met at 12-34 poses
# (stop.py): 96 holds give the accelerometer's fit about three times that, and its standard
# errors shrink as 1/sqrt(holds), so more would only slow each fit; 48 turns (the latest) give
# the gyroscope's fit more than the 33 turns of 34 poses.
MAX_BLOCKS = 96
MAX_TURNS = 48


@dataclass(frozen=True)
class Hold:
    start: float  # s, first still sample (its window's end)
    end: float  # s, last still sample
    mean: np.ndarray  # (3,) mean raw acceleration: the axis that was up
    n: int = 0  # samples
    var: np.ndarray = field(default_factory=lambda: np.zeros(3))  # (3,) per-axis sample
    #   variance of the raw acceleration (unbiased)


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
    rate: float = 0.0  # |w - still bias| of the last sample, raw gyroscope units
    turn_peak: float = 0.0  # its largest value since the last hold ended (the turn's peak)
    turn: dict | None = None  # the same in deg/s against the limit, once the unit is known
    #   (imucal.capture.run.turn_figures; set by the capture loop for the live view)


class StillDetector:
    def __init__(self, max_blocks: int = MAX_BLOCKS, max_turns: int = MAX_TURNS) -> None:
        self.max_blocks = max_blocks
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
        self.n_holds = 0  # holds found (self.holds keeps at most max_blocks of them)
        # the current still run's sums, centred on ref (acceleration) and g_ref (gyroscope)
        self.run_x = np.zeros(3)
        self.run_xx = np.zeros(3)
        self.run_g = np.zeros(3)
        self.run_gg = np.zeros(3)
        self.run_first = np.zeros((0, 4))  # its first two (t, w) rows
        self.run_tail = np.zeros((0, 7))  # its last window + 2 (t, acc, w) rows (see _close)
        self.confirmed = False  # it has lasted MIN_HOLD_S: a hold
        self.g_ref: np.ndarray | None = None
        self.g_n = 0  # still gyroscope samples of every hold
        self.g_sum = np.zeros(3)  # their sum, centred on g_ref
        self.g_ss = np.zeros(3)  # their squares about each hold's own mean
        self.turn: TurnBuffer | None = None  # the turn since the last hold ended
        self.pending: np.ndarray | None = None  # the turn into the hold being held
        self.chain: deque[Hold] = deque(maxlen=max_turns + 1)  # the latest consecutive holds
        self.turns: deque[np.ndarray] = deque(maxlen=max_turns)  # the turns between them
        self.turn_peak = 0.0
        self.rate_now = 0.0
        self.closed_at = -np.inf  # the last sample of a hold that ended in this batch

    def feed(self, t: np.ndarray, acc: np.ndarray, gyro: np.ndarray | None = None
             ) -> DetectorState:
        """Take a batch (times in s, raw acceleration (N, 3), raw rates (N, 3) or None); the
        guide after it."""
        if self.rate is None:
            cols = [t, acc] if gyro is None else [t, acc, gyro]
            self.first.append(np.column_stack(cols))
            rows = np.vstack(self.first)
            if len(rows) < RATE_SAMPLES:
                return self._state(False)
            self.first = []
            self.rate = 1.0 / float(np.median(np.diff(rows[:, 0])))
            self.window = max(5, round(WINDOW_S * self.rate))
            self.ref = rows[0, 1:4].copy()
            t, acc = rows[:, 0], rows[:, 1:4]
            gyro = rows[:, 4:7] if gyro is not None else None
            if gyro is not None:
                self.g_ref = gyro[0].copy()
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
        t = np.asarray(t, dtype=np.float64)
        rows = None
        self.closed_at = -np.inf
        if gyro is not None and self.g_ref is not None:
            rows = np.column_stack([t, np.asarray(gyro, dtype=np.float64)])
            # the turn's rate, about the still bias so far (raw units; none before a hold)
            rate = np.linalg.norm(rows[:, 1:] - self.gyro_bias(), axis=1)
            self.rate_now = float(rate[-1])
        new = self._runs(t, np.asarray(acc, dtype=np.float64), rows, still)
        if rows is not None:  # the peak of the moving samples since the last hold ended
            moving = rate[~still & (t > self.closed_at)]
            if len(moving):
                self.turn_peak = max(self.turn_peak, float(moving.max()))
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

    def _runs(self, t: np.ndarray, acc: np.ndarray, rows: np.ndarray | None,
              still: np.ndarray) -> list[Hold]:
        """Extend or close the current still run and every run in the batch (a loop over the
        runs, a few per batch, not over the samples); the gyroscope rows outside the holds go
        to the turn being made."""
        new = []
        runs = runs_of_true(still)
        pos = 0  # rows before this are placed (in a turn, or in a hold and not kept)
        for a, b in runs:
            if a > 0 or self.run_start is None:  # a run that starts here
                self._close(new)
                self._to_turn(rows, pos, a)
                pos = a
                self._open(float(t[a]))
            self._extend(acc, rows, a, b)
            if not self.confirmed:
                c = a + int(np.searchsorted(t[a:b], self.run_start + MIN_HOLD_S))
                if c < b:  # it becomes a hold at sample c: its turn ends where it began
                    self._to_turn(rows, pos, c)
                    self._confirm()
                    pos = b
                else:
                    self._to_turn(rows, pos, b)
                    pos = b
            else:
                pos = b
            self.t_last = float(t[b - 1])
            if b < len(still):  # it ends inside the batch
                self._close(new)
        if not len(runs):
            self._close(new)
        self._to_turn(rows, pos, len(t))
        return new

    def _open(self, start: float) -> None:
        self.run_start, self.run_sum, self.run_n = start, np.zeros(3), 0
        self.run_x, self.run_xx = np.zeros(3), np.zeros(3)
        self.run_g, self.run_gg = np.zeros(3), np.zeros(3)
        self.run_first = np.zeros((0, 4))
        self.run_tail = np.zeros((0, 7))
        self.confirmed = False

    def _extend(self, acc: np.ndarray, rows: np.ndarray | None, a: int, b: int) -> None:
        self.run_sum += acc[a:b].sum(axis=0)
        x = acc[a:b] - self.ref
        self.run_x += x.sum(axis=0)
        self.run_xx += (x * x).sum(axis=0)
        self.run_n += b - a
        keep = self.window + 2
        w = np.zeros((b - a, 3)) if rows is None else rows[a:b, 1:]
        t = np.zeros(b - a) if rows is None else rows[a:b, 0]
        self.run_tail = np.vstack([self.run_tail,
                                   np.column_stack([t, acc[a:b], w])[-keep:]])[-keep:]
        if rows is not None:
            g = rows[a:b, 1:] - self.g_ref
            self.run_g += g.sum(axis=0)
            self.run_gg += (g * g).sum(axis=0)
            if len(self.run_first) < 2:
                self.run_first = np.vstack([self.run_first, rows[a:b][:2]])[:2]

    def _to_turn(self, rows: np.ndarray | None, a: int, b: int) -> None:
        if rows is not None and self.turn is not None and b > a:
            self.turn.add(rows[a:b])

    def _confirm(self) -> None:
        self.confirmed = True
        if self.turn is not None and len(self.run_first) == 2:
            self.pending = self.turn.finish(self.run_start, self.run_first)
        self.turn = None

    def _close(self, new: list[Hold]) -> None:
        """End the current still run; a hold when it lasted MIN_HOLD_S. The trailing window
        sees a motion start only once it has grown past the noise (a smooth start takes about
        a window), so the run's last window of samples is taken off the hold and given to
        the turn that follows: they are the motion's start, not the pose."""
        if self.run_start is not None and self.t_last - self.run_start >= MIN_HOLD_S:
            cut = self.run_tail[2:]  # the last window
            self.run_sum -= cut[:, 1:4].sum(axis=0)
            x = cut[:, 1:4] - self.ref
            self.run_x -= x.sum(axis=0)
            self.run_xx -= (x * x).sum(axis=0)
            self.run_n -= len(cut)
            if self.g_ref is not None:
                g = cut[:, 4:] - self.g_ref
                self.run_g -= g.sum(axis=0)
                self.run_gg -= (g * g).sum(axis=0)
            n = self.run_n
            xm = self.run_x / n
            var = np.clip(self.run_xx / n - xm * xm, 0, None) * (n / max(n - 1, 1))
            end = float(self.run_tail[1, 0]) if self.g_ref is not None else self.t_last
            hold = Hold(self.run_start, end, self.run_sum / n, n, var)
            self._keep(hold)
            new.append(hold)
            if self.g_ref is not None:
                gm = self.run_g / n
                self.g_n += n
                self.g_sum += self.run_g
                self.g_ss += np.clip(self.run_gg - n * gm * gm, 0, None)
                if self.pending is not None:
                    self.chain.append(hold)
                    self.turns.append(self.pending)
                else:  # the first hold, or the turn into it was lost: a new chain
                    self.chain.clear()
                    self.turns.clear()
                    self.chain.append(hold)
                self.pending = None
                tail = self.run_tail[:, [0, 4, 5, 6]]
                self.turn = TurnBuffer(tail[:2])
                self.turn.add(tail[2:])
                self.turn_peak, self.closed_at = 0.0, self.t_last
        self.run_start, self.run_n, self.confirmed = None, 0, False

    def _keep(self, hold: Hold) -> None:
        """Keep ``hold`` for the accelerometer's fit; past ``max_blocks``, drop the one with
        fewer samples of the two kept holds whose directions are closest."""
        self.n_holds += 1
        self.holds.append(hold)
        if len(self.holds) <= self.max_blocks:
            return
        means = np.array([h.mean for h in self.holds]) - self.centre
        u = means / np.linalg.norm(means, axis=1, keepdims=True)
        cos = u @ u.T
        np.fill_diagonal(cos, -2.0)
        i, j = np.unravel_index(int(np.argmax(cos)), cos.shape)
        i, j = min(i, j), max(i, j)
        del self.holds[i if self.holds[i].n <= self.holds[j].n else j]

    def gyro_bias(self) -> np.ndarray:
        """The gyroscope's still bias so far (raw units): the mean over every hold's samples
        (method.md §4's 'all'); zero before the first hold."""
        if self.g_ref is None or self.g_n == 0:
            return np.zeros(3)
        return self.g_ref + self.g_sum / self.g_n

    def gyro_bias_var(self) -> np.ndarray:
        """(3,) the variance of :meth:`gyro_bias` for white noise: the pooled variance within
        the holds over the samples."""
        dof = max(self.g_n - self.n_holds, 1)
        return self.g_ss / dof / max(self.g_n, 1)

    def retained(self) -> dict[str, int]:
        """What the detector keeps for the running fits: holds, turns and their rows, bytes
        (the test that memory does not grow with the stream reads it)."""
        rows = sum(len(x) for x in self.turns) + (0 if self.pending is None
                                                  else len(self.pending))
        turn_bytes = (sum(x.nbytes for x in self.turns)
                      + (0 if self.turn is None else self.turn.nbytes)
                      + (0 if self.pending is None else self.pending.nbytes))
        return {"blocks": len(self.holds), "chain": len(self.chain), "turns": len(self.turns),
                "turn_rows": rows + (0 if self.turn is None else self.turn.n),
                "bytes": turn_bytes + len(self.holds) * 8 * 11 + len(self.chain) * 8 * 11
                + sum(x.nbytes for x in self.second)}

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
        return DetectorState(state=state, hold_s=hold, holds=self.n_holds,
                             orientations=self.orientations, coverage=self.covered,
                             next_pose=self.next_pose, up=self.up,
                             gravity=g / norm if norm > 0 else None, next_up=self.next_up,
                             rate=self.rate_now, turn_peak=self.turn_peak)


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


def guide_line(st: DetectorState, turn: dict | None = None) -> str:
    """The guide in words, for the terminal; ``turn`` the turn's figures in deg/s
    (imucal.capture.run.turn_figures), said while moving."""
    need = max(ORIENTATIONS_NEEDED - st.orientations, 0)
    if st.state == "waiting":
        return "waiting: keep the device still while the noise is measured"
    if st.state == "still":
        return (f"still {st.hold_s:4.1f} s (a hold counts from {MIN_HOLD_S:g} s, "
                f"{ADVISED_HOLD_S:g} s advised); {plural(st.orientations, 'pose')}")
    more = f", {need} more needed" if need else ""
    rate = ""
    if turn is not None and turn.get("turn_peak_dps") is not None and turn.get("rate_limit_dps"):
        fast = turn["turn_peak_dps"] > turn["rate_limit_dps"]
        rate = (f"; turn {turn['rate_dps']:.0f} deg/s, peak {turn['turn_peak_dps']:.0f} of "
                f"{turn['rate_limit_dps']:.0f} deg/s" + (" (too fast: turn more slowly)"
                                                           if fast else ""))
    return f"moving; {plural(st.orientations, 'pose')}{more}: next hold with {st.next_pose}{rate}"
