"""A guide to a good recording: what a session's poses and turns give the method, what they
lack, and what to record next (issue 14, item 7). Pure arithmetic on what the run already has.

- Poses (method.md §3): each still block's gravity direction in the calibrated sensor frame
  (the accelerometer reads +|g| along the axis pointing up, so this is "the axis that was up");
  the directions of the sphere no pose comes near (:func:`imucal.stages.accel_cv.coverage`, the
  same test the overfitting advice uses) and a few poses that would cover them.
- Holds (method.md §1): how long each pose was held still (its block and the detector's
  window around it) against the shortest hold that makes a block (the detector's ``min_len``
  and window, chosen from the data or given), the holds too short to count, named by time,
  and one advised hold (ADVISED_HOLD_S) for every recording.
- Turns (method.md §4, M5): each motion between consecutive blocks, its integrated rotation
  angle (calibrated gyroscope), how far it moved gravity, and its peak rate against a limit:
  a fraction of the gyroscope's full scale where that is known, and the rotation per sample
  M5's integrator handles (below).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from imucal.numerics.directions import DISTINCT_ANGLE_DEG, distinct_orientations
from imucal.session import Session
from imucal.stages.accel_cv import COVERAGE_ANGLE_DEG, axis_words, coverage
from imucal.stages.detect import Detection
from imucal.stages.gyro import MAX_STEP_DEG, GyroFit, small_turns_text
from imucal.stages.gyro_transitions import angle_between, transition_samples
from imucal.stages.quality import row_norms
from imucal.stages.saturation import CHUNK_ROWS, axis_saturated_runs

# A block shorter than this many times the detector's shortest is "near the minimum" (its
# hold near the shortest that counts): a slightly stricter detector (smaller k, a longer
# window) drops it, and its mean averages the noise over few samples.
NEAR_MIN_FACTOR = 1.5
# The hold advised to every user, whatever the file (the README's 2-4 s): on every shared
# recording and the sample the shortest hold that counts is 1-2 s, and 3 s clears 1.5 times
# that. Only a detector that needs longer (a window given by hand) raises it.
ADVISED_HOLD_S = 3.0
# A turn that moves gravity less than this lands in the same pose: the spacing at which
# imucal.numerics.directions.distinct_orientations counts two poses as distinct. The gyroscope
# fit's warning (imucal.stages.gyro) and the viewer use this same value.
MIN_TILT_DEG = DISTINCT_ANGLE_DEG
# Times listed in a sentence ("at 12.3, 40.1 s and 14 more"): the rest are in the viewer.
TIMES_LISTED = 6
# Peak rate limit where the full scale is known: this fraction of it leaves a margin before
# the gyroscope clips (a clipped turn is left out of the fit, method.md §4).
FULL_SCALE_FRACTION = 0.8
ORIENTATIONS_NEEDED = 9  # M2 has 9 parameters (method.md §3)
# Coverage called strong: a stray test direction or two at the meeting of three caps leaves no
# parameter undetermined (the suggestion still names the pose that would reach them).
GOOD_COVERAGE = 0.95
MAX_SUGGESTED = 6  # at most this many poses suggested (each covers a 45-degree cap)
# Integer codes of an ADC: a gyroscope in raw counts whose samples all lie inside one of these
# cannot read beyond it, so its full scale is at most the distance from its zero to the edge.
CODE_RANGES = ((0.0, 65535.0), (-32768.0, 32767.0))


@dataclass(frozen=True)
class PoseGuide:
    """The still blocks as poses (calibrated sensor frame)."""

    gravity: np.ndarray  # (B, 3) unit direction of each block's mean calibrated acceleration
    orientations: int  # distinct directions (15 degrees apart) over the whole session
    coverage: float  # fraction of the sphere within COVERAGE_ANGLE_DEG of a pose
    missing: np.ndarray  # (U, 3) test directions no pose comes within that angle of
    suggested: np.ndarray  # (S, 3) poses that would cover them (greedy), "this axis up"


@dataclass(frozen=True)
class HoldGuide:
    """How long each pose was held, against the shortest hold that counts."""

    duration_s: np.ndarray  # (B,) samples in the block / accelerometer rate
    min_s: float  # the detector's min_len in seconds (the shortest block)
    min_len: int  # samples
    min_source: str  # "chosen from the data" or "given"
    hold_s: np.ndarray  # (B,) each pose's hold: its block and the window's edges, s
    start_s: np.ndarray  # (B,) when each hold starts, s (its block's first sample)
    count_s: float  # the shortest hold that makes a block: min_len + window - 1 samples, s
    near_min: np.ndarray  # (B,) bool: held less than near_s
    near_s: float  # the hold whose block is NEAR_MIN_FACTOR x the shortest block, s
    short_holds: int  # still stretches the detector saw but too short for a block
    short_at_s: np.ndarray  # (short_holds,) when each starts, s (empty where unknown)
    min_hold_s: float | None  # the shortest still stretch that makes a block at the
    #                           shortest window the detector tried, s (what it counted with)
    recommended_s: float  # the hold advised: ADVISED_HOLD_S, or longer if the detector needs


@dataclass(frozen=True)
class TurnGuide:
    """Each motion between consecutive still blocks (empty without a gyroscope)."""

    times: np.ndarray  # (K, 2) first and last gyroscope sample of the motion, s
    angle_deg: np.ndarray  # (K,) integrated rotation (calibrated); NaN between segments
    tilt_deg: np.ndarray  # (K,) angle between the gravity directions before and after
    peak_rate: np.ndarray  # (K,) largest calibrated |w| during the motion, rad/s
    rate_limit: float  # rad/s, NaN without a gyroscope
    limit_source: str  # where rate_limit comes from, in words
    full_scale: float | None  # rad/s, where known
    full_scale_source: str
    min_tilt_deg: float
    fast: np.ndarray  # (K,) bool: peak_rate above rate_limit
    small: np.ndarray  # (K,) bool: tilt below min_tilt_deg
    saturated: np.ndarray  # (K,) bool: left out of the gyroscope fit (clipped samples)
    limit_brief: str = ""  # rate_limit's source in a few plain words, for the sentence


@dataclass(frozen=True)
class Guide:
    poses: PoseGuide
    holds: HoldGuide
    turns: TurnGuide
    strong: tuple[str, ...]  # what the session does well
    weak: tuple[str, ...]  # what it lacks
    record_next: tuple[str, ...]  # what to record next, as instructions

    def to_dict(self) -> dict:
        """The figures and the verdict for the calibration file (:func:`guide_summary`)."""
        return guide_summary(self)


def recording_guide(session: Session, det: Detection, block_times: np.ndarray,
                    gravity: np.ndarray, gyro_fits: list[tuple[int, GyroFit]],
                    gyro_rows: Callable[[int, int], np.ndarray] | None) -> Guide:
    """The guide of a run: ``gravity`` (B, 3) each block's mean calibrated acceleration (its
    segment's model), ``gyro_fits`` each segment's first block index and gyroscope fit,
    ``gyro_rows(lo, hi)`` the calibrated gyroscope's rows (None without a gyroscope), read a
    chunk at a time."""
    poses = _poses(gravity)
    holds = _holds(session, det, block_times)
    turns = _turns(session, block_times, poses.gravity, gyro_fits, gyro_rows)
    strong, weak, todo = _verdict(poses, holds, turns)
    return Guide(poses=poses, holds=holds, turns=turns, strong=strong, weak=weak,
                 record_next=todo)


def _poses(gravity: np.ndarray) -> PoseGuide:
    u = gravity / np.linalg.norm(gravity, axis=1, keepdims=True)
    missing, covered = coverage(u)
    return PoseGuide(gravity=u, orientations=distinct_orientations(u), coverage=covered,
                     missing=missing, suggested=suggest_poses(missing))


def suggest_poses(missing: np.ndarray, limit: int = MAX_SUGGESTED) -> np.ndarray:
    """Few directions whose 45-degree caps cover ``missing`` (greedy set cover: each step takes
    the missing direction with the most others within reach, and reports their mean)."""
    cos = np.cos(np.radians(COVERAGE_ANGLE_DEG))
    left, out = np.asarray(missing, dtype=float).reshape(-1, 3), []
    while len(left) and len(out) < limit:
        near = (left @ left.T) >= cos  # (U, U), U <= COVERAGE_DIRECTIONS
        cap = near[int(np.argmax(near.sum(axis=1)))]
        centre = left[cap].sum(axis=0)
        out.append(centre / np.linalg.norm(centre))
        left = left[~cap]
    return np.array(out).reshape(-1, 3)


def _holds(session: Session, det: Detection, block_times: np.ndarray) -> HoldGuide:
    rate = session.acc_rate
    duration = (det.blocks[:, 1] - det.blocks[:, 0]) / rate
    min_s = det.min_len / rate
    # M1 is still over a window around each sample: a hold makes a block window - 1 samples
    # shorter than itself (method.md §1), so the hold that counts is min_len + window - 1.
    edges = (det.window - 1) / rate
    count_s = min_s + edges
    tun = det.tuning
    source = ("chosen from the data" if tun is not None and "min_len" in tun.tuned
              else "given")
    starts = None if tun is None else tun.short_hold_starts
    short_at = (np.zeros(0) if starts is None or not len(starts)
                else np.asarray(session.t_acc[np.asarray(starts)], dtype=float))
    near_s = NEAR_MIN_FACTOR * min_s + edges
    # One advice for every file: ADVISED_HOLD_S, or (rounded up to half seconds) what keeps a
    # hold clear of the minimum where this detector needs more.
    need = np.ceil(near_s * 2) / 2
    hold = duration + edges
    return HoldGuide(duration_s=duration, min_s=min_s, min_len=int(det.min_len),
                     min_source=source, hold_s=hold,
                     start_s=np.asarray(block_times[:, 0], dtype=float).copy(),
                     count_s=float(count_s), near_min=duration < NEAR_MIN_FACTOR * min_s,
                     near_s=float(near_s),
                     short_holds=tun.short_holds if tun is not None else 0,
                     short_at_s=short_at, min_hold_s=tun.min_hold_s if tun is not None else None,
                     recommended_s=float(max(ADVISED_HOLD_S, need)))


def at_times(t: np.ndarray, limit: int = TIMES_LISTED) -> str:
    """"at 12.3, 40.1 and 55.0 s" ("... s and 14 more"): when things happened, for a
    sentence."""
    t = np.sort(np.asarray(t, dtype=float))
    shown = [f"{x:.1f}" for x in t[:limit]]
    if not shown:
        return ""
    more = len(t) - len(shown)
    if more:
        return f"at {', '.join(shown)} s and {more} more"
    if len(shown) == 1:
        return f"at {shown[0]} s"
    return f"at {', '.join(shown[:-1])} and {shown[-1]} s"


def _peak_rates(rows: Callable[[int, int], np.ndarray], starts: np.ndarray, ends: np.ndarray,
                n: int, chunk: int = 1 << 16) -> np.ndarray:
    """Largest calibrated ``|w|`` over each turn's samples ``[starts[k], ends[k])`` (both
    sorted, each turn one sample or more), from ``rows(lo, hi)`` of the signal (``n`` rows) a
    chunk at a time: one chunk's norm at once, never the signal's (a maximum is exact in any
    order). A loop over chunks and the turns meeting each (tens to hundreds): linear time."""
    peak = np.full(len(starts), -np.inf)
    if len(starts) == 0:
        return peak
    first = int(starts[0]) // chunk * chunk  # on the calibration's chunk grid: no extra rows
    for c0 in range(first, min(int(ends[-1]), n), chunk):
        c1 = min(n, c0 + chunk)
        k0 = int(np.searchsorted(ends, c0, side="right"))  # turns ending after c0
        k1 = int(np.searchsorted(starts, c1, side="left"))  # turns starting before c1
        if k1 <= k0:
            continue
        # Column by column: np.linalg.norm's sums in the same order, without its slow
        # reduction over rows of three (5x the time per chunk).
        norm = row_norms(rows(c0, c1))
        for k in range(k0, k1):
            a, b = max(int(starts[k]), c0), min(int(ends[k]), c1)
            if b > a:
                peak[k] = np.maximum(peak[k], norm[a - c0:b - c0].max())
    return peak


def _turns(session: Session, block_times: np.ndarray, u: np.ndarray,
           gyro_fits: list[tuple[int, GyroFit]],
           gyro_rows: Callable[[int, int], np.ndarray] | None) -> TurnGuide:
    K = max(len(block_times) - 1, 0)
    tilt = angle_between(u[1:], u[:-1]) if K else np.zeros(0)  # deg
    if not session.has_gyro or gyro_rows is None or not gyro_fits or K == 0:
        empty = np.zeros(0)
        return TurnGuide(np.zeros((0, 2)), empty, empty, empty, float("nan"), "no gyroscope",
                         None, "no gyroscope", MIN_TILT_DEG, empty.astype(bool),
                         empty.astype(bool), empty.astype(bool))
    t = session.t_gyro
    s, e = transition_samples(t, block_times)
    peak = _peak_rates(gyro_rows, s, e + 1, len(t))
    angle = np.full(K, np.nan)
    saturated = np.zeros(K, dtype=bool)
    for b0, fit in gyro_fits:  # segment turns: b0 .. b0 + len - 1; between segments: none
        n = len(fit.rotation_angle)
        angle[b0:b0 + n] = np.degrees(fit.rotation_angle)
        saturated[b0:b0 + n] = fit.excluded
    full, full_src = gyro_full_scale(session, gyro_fits[0][1])
    step_limit = np.radians(MAX_STEP_DEG) * float(session.gyro_rate)
    brief = f"{MAX_STEP_DEG:g} deg per sample at {session.gyro_rate:.4g} Hz"
    limit, src = step_limit, f"{brief}, what M5's integration carries without visible error"
    if full is not None and FULL_SCALE_FRACTION * full < step_limit:
        limit = FULL_SCALE_FRACTION * full
        brief = f"{FULL_SCALE_FRACTION:.0%} of the gyroscope's full scale"
        src = f"{FULL_SCALE_FRACTION:.0%} of the full scale, {full_src}"
    return TurnGuide(times=np.column_stack([t[s], t[e]]), angle_deg=angle, tilt_deg=tilt,
                     peak_rate=peak, rate_limit=float(limit), limit_source=src, full_scale=full,
                     full_scale_source=full_src, min_tilt_deg=MIN_TILT_DEG, fast=peak > limit,
                     small=tilt < MIN_TILT_DEG, saturated=saturated, limit_brief=brief)


def gyro_full_scale(session: Session, fit: GyroFit) -> tuple[float | None, str]:
    """The gyroscope's full scale in rad/s (the smallest over its axes) where the recording
    shows it, and how: the level it clips at, else the edge of its integer codes for raw
    counts; None where neither tells (input in rad/s that never clips)."""
    w = session.gyro
    per_unit = fit.nominal_scale if session.gyro_unit == "counts" else 1.0  # rad/s per raw
    zero = fit.model.b
    levels = []
    # The level each clipped axis sits at, from its zero: every axis's runs in one pass over
    # the rows (a column's view would read every row once per axis).
    for axis, runs in enumerate(axis_saturated_runs(w)):
        if len(runs):
            levels.append(min(np.abs(w[a:b, axis] - zero[axis]).min() for a, b in runs)
                          * per_unit)
    if levels:
        return float(min(levels)), "the level the gyroscope clipped at here"
    if session.gyro_unit == "counts" and _integers(w):
        lo, hi = float(w.min()), float(w.max())
        for a, b in CODE_RANGES:
            if a <= lo and hi <= b:
                edge = np.minimum(b - zero, zero - a).min() * per_unit
                return float(edge), (f"at most the edge of its {int(b - a + 1)} integer "
                                     "codes from its zero")
    return None, "not known: the gyroscope never clipped and its unit is not raw codes"


def _integers(w: np.ndarray) -> bool:
    """Is every value a whole number? (a chunk of rows at a time)"""
    return all(np.all(c == np.round(c)) for c in
               (w[i:i + CHUNK_ROWS] for i in range(0, len(w), CHUNK_ROWS)))


def _verdict(poses: PoseGuide, holds: HoldGuide, turns: TurnGuide
             ) -> tuple[tuple[str, ...], tuple[str, ...], tuple[str, ...]]:
    """What is strong, what is weak, what to record next: one sentence per finding."""
    strong: list[str] = []
    weak: list[str] = []
    todo: list[str] = []
    for judge, what in ((_judge_poses, poses), (_judge_holds, holds), (_judge_turns, turns)):
        judge(what, strong, weak, todo)
    if not todo:
        todo.append("nothing: the session covers the sphere, holds long enough and turns "
                    "within the limits")
    return tuple(strong), tuple(weak), tuple(todo)


def _judge_poses(poses: PoseGuide, strong: list[str], weak: list[str], todo: list[str]
                 ) -> None:
    cover = (f"{poses.orientations} distinct orientations ({ORIENTATIONS_NEEDED} needed), "
             f"{int(100 * poses.coverage)} % of the sphere within {COVERAGE_ANGLE_DEG:g} deg "
             "of a pose")  # rounded down: 100 % only when nothing is missing
    good = poses.coverage >= GOOD_COVERAGE and poses.orientations >= ORIENTATIONS_NEEDED
    (strong if good else weak).append(cover)
    if len(poses.suggested):
        where = ", ".join(f"({axis_words(v)})" for v in poses.suggested)
        n = len(poses.suggested)
        reach = (poses.missing @ poses.suggested.T).max(axis=1)
        more = (", then look again: some directions stay uncovered"
                if np.any(reach < np.cos(np.radians(COVERAGE_ANGLE_DEG))) else "")
        todo.append(f"hold {n} more pose{'s' if n > 1 else ''}, with {where} pointing up{more}")
    elif poses.orientations < ORIENTATIONS_NEEDED:
        todo.append(f"hold {ORIENTATIONS_NEEDED - poses.orientations} more poses in new "
                    f"orientations, each tilted {MIN_TILT_DEG:g} deg or more from the others")


def _judge_holds(holds: HoldGuide, strong: list[str], weak: list[str], todo: list[str]
                 ) -> None:
    """One minimum (the shortest hold that counts), one advice (``recommended_s``), and the
    holds that fall short named by when they start."""
    med = float(np.median(holds.hold_s)) if len(holds.hold_s) else float("nan")
    n_near = int(holds.near_min.sum())
    poses = (f"{len(holds.hold_s)} poses held still {med:.2g} s at the median; a hold counts "
             f"from {holds.count_s:.2g} s")
    if not (n_near or holds.short_holds):
        strong.append(poses)
        return
    parts = []
    if holds.short_holds:
        when = at_times(holds.short_at_s)
        parts.append(f"{holds.short_holds} shorter holds did not count"
                     + (f" ({when})" if when else ""))
    if n_near:
        parts.append(f"{n_near} barely counted, held under {holds.near_s:.2g} s "
                     f"({at_times(holds.start_s[holds.near_min])})")
    weak.append(f"{poses}: {'; '.join(parts)}")
    todo.append(f"hold each pose still for {holds.recommended_s:g} s or more")


def _judge_turns(turns: TurnGuide, strong: list[str], weak: list[str], todo: list[str]
                 ) -> None:
    K = len(turns.peak_rate)
    if K == 0:
        return
    # In plain words; the limit's full source (M5's integration, the clipping level) is in
    # calib.json's guide.turn_rate_limit_source and the viewer's guide info.
    turn = (f"{K} turns, the fastest at {turns.peak_rate.max():.3g} rad/s against a limit "
            f"of {turns.rate_limit:.3g} rad/s ({turns.limit_brief or turns.limit_source})")
    n_fast, n_small, n_sat = (int(turns.fast.sum()), int(turns.small.sum()),
                              int(turns.saturated.sum()))
    if n_fast or n_sat:
        extra = f", {n_sat} through clipped samples" if n_sat else ""
        weak.append(f"{turn}: {n_fast} faster than the limit{extra}")
        todo.append(f"turn more slowly: keep below {turns.rate_limit:.3g} rad/s "
                    f"({np.degrees(turns.rate_limit):.0f} deg/s)")
    else:
        strong.append(turn)
    if n_small:
        weak.append(small_turns_text(n_small, K) + f" ({at_times(turns.times[turns.small, 0])})")
        todo.append(f"tilt {MIN_TILT_DEG:g} deg or more between consecutive poses")


def guide_summary(guide: Guide) -> dict:
    """The guide's figures and verdict, small enough for the calibration file (no arrays)."""
    def f(x: float | None) -> float | None:
        return None if x is None or not np.isfinite(x) else float(x)

    h, t = guide.holds, guide.turns
    return {"orientations": guide.poses.orientations, "coverage": f(guide.poses.coverage),
            "min_block_s": f(h.min_s), "min_block_source": h.min_source,
            "min_hold_s": f(h.count_s), "advised_hold_s": f(h.recommended_s),
            "blocks_near_minimum": int(h.near_min.sum()), "short_holds": h.short_holds,
            "short_holds_at_s": [float(x) for x in h.short_at_s],
            "turn_rate_limit_rad_s": f(t.rate_limit), "turn_rate_limit_source": t.limit_source,
            "gyro_full_scale_rad_s": f(t.full_scale), "turns_over_limit": int(t.fast.sum()),
            "turns_under_min_tilt": int(t.small.sum()), "strong": list(guide.strong),
            "weak": list(guide.weak), "record_next": list(guide.record_next)}
