"""Check that the grouping's fast split search picks what the exhaustive search picks.

    .venv/bin/python bench/check_group.py [--seeds 40] [--poses 40 120]

``imucal.stages.group.best_split`` scores every boundary with a Gauss-Newton model and fits only the
best few exactly; the exhaustive search (the original implementation, kept here) fits both
sides of every boundary. For synthetic sessions, steady and with a change of parameters at a
random place, both run on the same block means and must return the same boundaries, the same
change figures and the same segments. Prints the fits each needed.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

import imucal
import imucal.pipeline as P
import imucal.stages.group as G
from imucal.settings import Settings
from imucal.synth import make_session


def exhaustive_group(m, theta, lam, settings):
    """The original O(B^2) binary segmentation: two LM fits for every boundary (with the
    product's rule that a side keeps at least 9 distinct orientations)."""
    tests = []
    fits = [0]

    def fit(pts, start):
        fits[0] += 1
        return G._fit(pts, start, lam)

    def split(i0, i1, start):
        k = settings.min_blocks
        if i1 - i0 < 2 * k:
            return [(i0, i1)]
        start, _, one = fit(m[i0:i1], start)
        best = None
        for j in range(i0 + k, i1 - k + 1):
            th_a, c_a, d_a = fit(m[i0:j], start)
            th_b, c_b, d_b = fit(m[j:i1], start)
            if best is None or c_a + c_b < best[0]:
                best = (c_a + c_b, j, th_a, th_b, d_a + d_b)
        _, j, th_a, th_b, two = best
        change = float(np.sqrt(max(one - two, 0.0) / (i1 - i0)))
        s = change > settings.delta
        veto = getattr(G, "distinct_orientations", None)  # the product's own rule, if any
        if s and veto is not None and min(veto(m[i0:j]), veto(m[j:i1])) < 9:
            s = False
        tests.append((j, change, s))
        if not s:
            return [(i0, i1)]
        return split(i0, j, th_a) + split(j, i1, th_b)

    n = len(m)
    if settings.single_segment or n < 2 * settings.min_blocks:
        return [(0, n)], [], 0
    return split(0, n, theta), tests, fits[0]


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=25)
    ap.add_argument("--poses", type=int, nargs="+", default=[40, 120])
    args = ap.parse_args()
    captured = {}
    real = P.group_blocks

    def capture(means, theta, lam, settings=Settings().group):
        captured.update(m=means, theta=theta, lam=lam, settings=settings)
        return real(means, theta, lam, settings)

    P.group_blocks = capture
    counted = [0]
    real_fit = G._fit

    def counting_fit(*a, **k):
        counted[0] += 1
        return real_fit(*a, **k)

    G._fit = counting_fit
    bad = 0
    total = 0
    fits_fast = fits_slow = 0
    t_fast = t_slow = 0.0
    rng = np.random.default_rng(0)
    for poses in args.poses:
        for seed in range(args.seeds):
            change = None if seed % 2 == 0 else float(rng.uniform(0.3, 0.7))
            noise = float(rng.choice([0.001, 0.003, 0.01, 0.03]))
            session, _ = make_session(poses=poses, seed=1000 + seed, change_at=change,
                                      acc_noise=noise)
            try:
                imucal.calibrate(session)
            except imucal.ImucalError:
                continue
            m, theta, lam, st = (captured[k] for k in ("m", "theta", "lam", "settings"))
            counted[0] = 0
            t0 = time.perf_counter()
            fast = real(m, theta, lam, st)
            t_fast += time.perf_counter() - t0
            fits_fast += counted[0]
            t0 = time.perf_counter()
            segs, tests, n_fits = exhaustive_group(m, theta, lam, st)
            t_slow += time.perf_counter() - t0
            fits_slow += n_fits
            got = [(t.block, t.change, t.split) for t in fast.tests]
            same = fast.segments == segs and got == tests
            total += 1
            if not same:
                bad += 1
                print(f"DIFFERENT poses={poses} seed={1000 + seed} change_at={change} "
                      f"acc_noise={noise}: "
                      f"fast {fast.segments} {got} vs exhaustive {segs} {tests}")
    print(f"{total} sessions, {bad} different; fits {fits_fast} vs {fits_slow} exhaustive; "
          f"time {t_fast:.2f} s vs {t_slow:.2f} s")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
