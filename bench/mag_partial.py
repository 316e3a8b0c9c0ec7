"""The magnetometer's shape held towards a sphere (M8r) against the plain ellipsoid and the
sphere, where the field reached part of the sphere of directions (issue 23, item 2).

    PYTHONPATH=. .venv/bin/python bench/mag_partial.py [../shared/data]

Synthetic sessions (imucal.synth, truth known) of few poses: the field's directions are those
of the poses and the turns between them. For each seed: the soft iron's largest entry error
(|M - M_true|, max), the hard iron's (|b - b_true| / F, max) and the field's (|F / F_true -
1|), of the three fits on every sample, and the norm residual held out (each half of the
recording's time judged by the other half's fit of the same kind, RMS %). Then the shared
recordings with a magnetometer and no still blocks given: x-io's (partial coverage) and the
full sphere, in sample and held out.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from imucal.numerics.ellipsoid import fit_ellipsoid, sphere_fit
from imucal.numerics.ellipsoid_tikhonov import regularised_fit
from imucal.stages.mag import _coverage, _held_out_pct
from imucal.synth import make_session


def _M(G: np.ndarray) -> tuple[np.ndarray, float]:
    F = float(np.linalg.det(G) ** (-1 / 3))
    return F * G, F


FITS = {"regularised": lambda x: regularised_fit(x).fit, "plain": fit_ellipsoid,
        "sphere": sphere_fit}


def held_out(x: np.ndarray, make) -> float:
    cut = len(x) // 2
    r = []
    for fit_on, judge in ((x[cut:], x[:cut]), (x[:cut], x[cut:])):
        try:
            r.append(make(fit_on).residuals(judge))
        except (ValueError, np.linalg.LinAlgError):
            return float("nan")
    r = np.concatenate(r)
    return float(100 * np.sqrt(np.mean(r * r)))


def synthetic(poses: int, seeds: range) -> None:
    print(f"\n### {poses} poses (2 s holds, 1.5 s turns, magnetometer 25 Hz, noise 0.4 % of "
          "the field)\n")
    print("| seed | coverage | soft iron error: reg / plain / sphere | hard iron error (% F) "
          "| field error (%) | held out %: reg / plain / sphere |")
    print("|---:|---:|---|---|---|---|")
    errs = {k: [] for k in FITS}
    for seed in seeds:
        s, truth = make_session(seed=seed, poses=poses, still=2.0, move=1.5, init_still=2.0,
                                acc_rate=50.0, mag_rate=25.0)
        x = np.asarray(s.others[0].values, float)
        t = truth.mag
        row = {}
        for name, make in FITS.items():
            f = make(x)
            M, F = _M(f.G)
            row[name] = (float(np.abs(M - t.M).max()), float(100 * np.abs(f.c - t.b).max() / F),
                         float(100 * abs(F / t.field - 1)), held_out(x, make))
            errs[name].append(row[name])
        cov = _coverage(x, sphere_fit(x))

        def cell(i: int, fmt: str, row=row) -> str:
            return " / ".join(format(row[k][i], fmt) for k in FITS)

        print(f"| {seed} | {cov:.0%} | {cell(0, '.4f')} | {cell(1, '.2f')} | {cell(2, '.2f')} "
              f"| {cell(3, '.2f')} |")
    e = {k: np.array(v) for k, v in errs.items()}
    med = {k: np.nanmedian(v, axis=0) for k, v in e.items()}
    worst = {k: np.nanmax(v, axis=0) for k, v in e.items()}
    for label, d in (("median", med), ("worst", worst)):
        print(f"| {label} | | " + " | ".join(" / ".join(format(d[k][i], f) for k in FITS)
                                             for i, f in ((0, ".4f"), (1, ".2f"), (2, ".2f"),
                                                          (3, ".2f"))) + " |")


def shared(folder: Path) -> None:
    import h5py
    import polars as pl

    df = pl.read_csv(folder / "xio_fusion" / "sensor_data.csv")
    xio = df.select([c for c in df.columns if c.startswith("Magnetometer")]).to_numpy()
    with h5py.File(folder / "sunsided_mpu6050_hmc5883l" / "full-sphere" /
                   "hmc5883l_compass.mat") as f:
        sphere = f["compassBuffer"][:][1:].T.copy()
    print("\n### Shared recordings (every sample, no disturbance search)\n")
    print("| recording | fit | in sample % | held out % | field | lambda |")
    print("|---|---|---:|---:|---:|---:|")
    for name, x in (("x-io Fusion (uT)", xio), ("full sphere (gauss)", sphere)):
        for kind, make in FITS.items():
            f = make(x)
            r = f.residuals(x)
            lam = regularised_fit(x).lam if kind == "regularised" else float("nan")
            held = held_out(x, make)
            if kind == "regularised":  # as calibrate says it: None where a half reaches
                # under 10 % of the directions (imucal.stages.mag._held_out_pct)
                judged = _held_out_pct(x, np.arange(len(x), dtype=float), f)
                held_txt = f"{held:.3f}" if judged is not None else f"not judged ({held:.1f})"
            else:
                held_txt = f"{held:.3f}"
            print(f"| {name} | {kind} | {100 * np.sqrt(np.mean(r * r)):.3f} | "
                  f"{held_txt} | {_M(f.G)[1]:.4g} | {lam:.2g} |")


def main(folder: str = "../shared/data") -> None:
    synthetic(5, range(10))
    synthetic(8, range(10))
    synthetic(16, range(5))
    shared(Path(folder))


if __name__ == "__main__":
    main(*sys.argv[1:])
