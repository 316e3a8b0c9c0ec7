"""Check the grouping (method.md §2): its fast split search, and how often it splits wrongly.

    .venv/bin/python bench/check_group.py [--seeds 25] [--poses 40 120]
    .venv/bin/python bench/check_group.py --rates 300 [--split-alpha 0.001 | --delta 0.01]

Search: ``imucal.stages.group.best_split`` scores every boundary with a Gauss-Newton model and
fits only the best few exactly; the exhaustive search (kept here) fits both sides of every
boundary. For synthetic sessions, steady and with a change of parameters at a random place,
the grouping runs once with each search on the same block means and must return the same
boundaries, the same test figures and the same segments. Prints the fits each needed.

Rates: over ``--rates`` seeds, a steady session and the same session with a knock (each scale
changed by 1-2 %, the bias moved by 10-30 mg, at 35-65 % of the poses), at noise 1, 3 or 9 mg,
in g, m/s^2 or raw counts, with 30, 40 or 60 poses. Counts the steady sessions split (false
splits), the knocked ones not split in two (missed), splits more than two blocks from the
change, and the worst after-calibration static norm error of the knocked sessions against
the noise floor (the same figure for the steady session with the same seed), counted where
the change is at least ``min_blocks`` blocks from both ends: nearer, the boundary cannot be
placed at the change.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

import imucal
import imucal.pipeline as P
import imucal.stages.group as G
from imucal.synth import make_session


def exhaustive_best_split(m, w, start, lam, js, fits):
    """Both sides fitted at every boundary: what best_split must agree with."""
    best = None
    for j in js:
        j = int(j)
        th_a, c_a, d_a = G._fit(m[:j], w[:j], start, lam, centre=start)
        th_b, c_b, d_b = G._fit(m[j:], w[j:], start, lam, centre=start)
        fits[0] += 2
        if best is None or c_a + c_b < best[0]:
            best = (c_a + c_b, j, th_a, th_b, d_a + d_b)
    _, j, th_a, th_b, two = best
    return j, th_a, th_b, two


def check_search(seeds: int, poses_list: list[int]) -> int:
    captured = {}
    real = P.group_blocks

    def capture(means, var, theta, lam, settings):
        captured.update(args=(means, var, theta, lam, settings))
        return real(means, var, theta, lam, settings)

    P.group_blocks = capture
    counted = [0]
    real_fit = G._fit

    def counting_fit(*a, **k):
        counted[0] += 1
        return real_fit(*a, **k)

    fast_split = G.best_split
    bad = total = fits_fast = fits_slow = 0
    t_fast = t_slow = 0.0
    rng = np.random.default_rng(0)
    for poses in poses_list:
        for seed in range(seeds):
            change = None if seed % 2 == 0 else float(rng.uniform(0.3, 0.7))
            noise = float(rng.choice([0.001, 0.003, 0.01, 0.03]))
            session, _ = make_session(poses=poses, seed=1000 + seed, change_at=change,
                                      acc_noise=noise)
            try:
                imucal.calibrate(session)
            except imucal.ImucalError:
                continue
            args = captured["args"]
            G._fit, counted[0] = counting_fit, 0
            t0 = time.perf_counter()
            fast = real(*args)
            t_fast += time.perf_counter() - t0
            G._fit = real_fit
            fits_fast += counted[0]
            slow_fits = [0]
            G.best_split = lambda m, w, s, lam, js, f=slow_fits: exhaustive_best_split(
                m, w, s, lam, js, f)
            t0 = time.perf_counter()
            slow = real(*args)
            t_slow += time.perf_counter() - t0
            G.best_split = fast_split
            fits_slow += slow_fits[0]
            got = [(t.block, t.f, t.split) for t in fast.tests]
            want = [(t.block, t.f, t.split) for t in slow.tests]
            same = fast.segments == slow.segments and all(
                a[0] == b[0] and a[2] == b[2] and np.isclose(a[1], b[1], rtol=1e-6, equal_nan=True)
                for a, b in zip(got, want)) and len(got) == len(want)
            total += 1
            if not same:
                bad += 1
                print(f"DIFFERENT poses={poses} seed={1000 + seed} change_at={change} "
                      f"acc_noise={noise}: fast {fast.segments} {got} vs exhaustive "
                      f"{slow.segments} {want}")
    P.group_blocks = real
    print(f"{total} sessions, {bad} different; fits {fits_fast} vs {fits_slow} (exhaustive "
          f"boundary search); time {t_fast:.2f} s vs {t_slow:.2f} s")
    return 1 if bad else 0


def rates(n: int, overrides: dict) -> int:
    false = missed = missed_near_end = far = 0
    worst = (0.0, None)
    t0 = time.perf_counter()
    for i in range(n):
        seed = 5000 + i
        rng = np.random.default_rng(seed)
        noise = float(rng.choice([0.001, 0.003, 0.009]))
        unit = str(rng.choice(["g", "counts", "m/s^2"]))
        poses = int(rng.choice([30, 40, 60]))
        kw = dict(poses=poses, seed=seed, acc_noise=noise, acc_unit=unit)
        steady = imucal.calibrate(make_session(**kw)[0], **overrides)
        if len(steady.segments) != 1:
            false += 1
            print(f"FALSE SPLIT {kw}: {[t.reason for t in steady.grouping.tests]}")
        scale, bias, at = rng.uniform(0.01, 0.02), rng.uniform(0.01, 0.03), rng.uniform(.35, .65)
        session, truth = make_session(**kw, change_at=float(at), acc_change=(scale, bias))
        r = imucal.calibrate(session, **overrides)
        true_j = int(np.searchsorted(r.block_times[:, 0], truth.t_change))
        k = r.settings.min_blocks
        near_end = min(true_j, len(r.block_times) - true_j) < k
        if len(r.segments) != 2:
            missed += 1
            missed_near_end += near_end
            print(f"MISSED {kw} change before block {true_j} of {len(r.block_times)}"
                  f"{' (a side would have fewer than min_blocks)' if near_end else ''}: "
                  f"{len(r.segments)} segments, {[t.reason for t in r.grouping.tests]}")
            continue
        j = r.segments[1].blocks[0]
        if abs(j - true_j) > 2:
            far += 1
            print(f"FAR {kw}: split at block {j}, change before block {true_j}")
        ratio = r.quality.static_norm_rms_mg.after / steady.quality.static_norm_rms_mg.after
        if ratio > worst[0] and not near_end:
            worst = (ratio, f"{kw} change at {at:.2f}: split at {j}, change at {true_j}")
    print(f"{n} steady sessions: {false} split ({false / n:.1%}); {n} knocked: {missed} not "
          f"in two segments ({missed / n:.1%}; {missed_near_end} of them with the change fewer "
          f"than min_blocks from an end), {far} split more than 2 blocks from the change; "
          f"worst static norm error, knocked / steady, where the change is min_blocks from "
          f"both ends: {worst[0]:.2f} ({worst[1]}); "
          f"{time.perf_counter() - t0:.0f} s")
    return 0


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=25)
    ap.add_argument("--poses", type=int, nargs="+", default=[40, 120])
    ap.add_argument("--rates", type=int, default=0, metavar="N",
                    help="measure false and missed split rates over N seeds instead")
    ap.add_argument("--split-alpha", type=float, default=None)
    ap.add_argument("--delta", type=float, default=None)
    args = ap.parse_args()
    if args.rates:
        over = {k: v for k, v in (("split_alpha", args.split_alpha), ("delta", args.delta))
                if v is not None}
        return rates(args.rates, over)
    return check_search(args.seeds, args.poses)


if __name__ == "__main__":
    sys.exit(main())
