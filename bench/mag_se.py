"""Are the magnetometer's standard errors honest on real data? A check that needs no truth:
fit each contiguous piece of a recording by itself and compare the pieces' differences with
the standard errors each fit reports (bench/mag_se.md reports the figures).

    PYTHONPATH=. .venv/bin/python bench/mag_se.py [../shared/data]

For the full sphere (sunsided's HMC5883L) and the BROAD trials 02, 05 and 24: the recording
cut into K = 2 and 3 contiguous pieces of equal time, each calibrated by
``calibrate_magnetometer`` alone (no still blocks: M, b and the field), and for every pair of
pieces and every parameter (M's six entries, b, the field) the z-score ``(x_i - x_j) /
sqrt(s_i^2 + s_j^2)``. Honest standard errors give an RMS z near 1. Reported with the
standard errors the fit gives today (M8s: scaled by the design effect of the residual's
correlation) and with those of independent samples (the same divided by ``sqrt(deff)``: what
imucal reported before). A parameter held (the soft iron of a piece that reaches too few
directions) is left out of its pair.

Then the alternatives measured before M8s was chosen, on the halves of each recording (the
ellipsoid fitted to each half's samples): the white covariance, a Newey-West sandwich of the
scores with the Bartlett kernel at three bandwidths, the block jackknife without and with the
leave-out normal matrix (Sokal's c = 5 and 8) and M8s, each as the halves' RMS z.
"""

from __future__ import annotations

import sys
from itertools import combinations
from pathlib import Path

import h5py
import numpy as np

from imucal.numerics.block_jackknife import block_jackknife_cov, correlation_window
from imucal.numerics.ellipsoid import EllipsoidFit, _normalise, _res_jac, fit_ellipsoid
from imucal.numerics.ellipsoid import vec_from_sym as _vec
from imucal.stages.mag import MagFit, MagUnfit, _derived, _derived_cov, calibrate_magnetometer
from imucal.streams import Stream

BROAD = ("02_undisturbed_slow_rotation_B", "05_undisturbed_slow_rotation_with_breaks_B",
         "24_disturbed_tapping_A")


def recordings(data: Path) -> list[Stream]:
    path = data / "sunsided_mpu6050_hmc5883l" / "full-sphere" / "hmc5883l_compass.mat"
    with h5py.File(path) as f:
        buf = f["compassBuffer"][:]
    out = [Stream("mag", "full sphere", buf[0], buf[1:].T.copy(), "gauss", str(path))]
    for name in BROAD:
        with h5py.File(data / "broad" / f"{name}.hdf5") as f:
            mag, rate = f["imu_mag"][:], float(f.attrs["sampling_rate"])
        out.append(Stream("mag", name[:2], np.arange(len(mag)) / rate, mag, "uT", name))
    return out


def values(fit: MagFit) -> tuple[np.ndarray, np.ndarray]:
    """The 10 parameters (M's upper triangle, b, the field) and their standard errors."""
    iu = np.triu_indices(3)
    return (np.r_[fit.M[iu], fit.b, fit.field],
            np.r_[fit.std_M[iu], fit.std_b, fit.std_field])


def pieces(stream: Stream, k: int) -> list[MagFit | None]:
    edges = np.linspace(stream.t[0], stream.t[-1] + 1e-9, k + 1)
    out = []
    for a, b in zip(edges[:-1], edges[1:]):
        inside = (stream.t >= a) & (stream.t < b)
        try:
            out.append(calibrate_magnetometer(Stream(stream.kind, stream.instance,
                                                     stream.t[inside], stream.values[inside],
                                                     stream.unit, stream.origin)))
        except MagUnfit:
            out.append(None)
    return out


def z_scores(fits: list[MagFit | None]) -> tuple[np.ndarray, np.ndarray]:
    """Every pair's z-scores with today's standard errors and with the white ones."""
    now, white = [], []
    for f, g in combinations([f for f in fits if f is not None], 2):
        (x, s), (y, t) = values(f), values(g)
        ok = (s > 0) & (t > 0)
        now.append(((x - y) / np.hypot(s, t))[ok])
        white.append(((x - y) / np.hypot(s / np.sqrt(f.se_design_effect),
                                         t / np.sqrt(g.se_design_effect)))[ok])
    return np.concatenate(now), np.concatenate(white)


def rms(z: np.ndarray) -> float:
    return float(np.sqrt(np.mean(z * z)))


def main(data: str = "../shared/data") -> None:
    print("| recording | pieces | design effect (block, s) | RMS z white (before) | "
          "RMS z now | max abs z now | SE now / before, whole recording |")
    print("|---|---:|---|---:|---:|---:|---:|")
    for stream in recordings(Path(data)):
        whole = calibrate_magnetometer(stream)
        for k in (2, 3):
            fits = pieces(stream, k)
            now, white = z_scores(fits)
            de = ", ".join(f"{f.se_design_effect:.0f} ({f.se_block_s:.2g})" if f else
                           "not fitted"
                           for f in fits)
            print(f"| {stream.instance} | {k} | {de} | {rms(white):.1f} | {rms(now):.2f} | "
                  f"{np.abs(now).max():.1f} | {np.sqrt(whole.se_design_effect):.1f}x |")
    print()
    print("| covariance | " + " | ".join(s.instance for s in recordings(Path(data))) + " |")
    print("|---|" + "---:|" * 4)
    rows: dict[str, list[str]] = {}
    for stream in recordings(Path(data)):
        for name, z in alternatives(stream).items():
            rows.setdefault(name, []).append(f"{z:.2f}")
    for name, zs in rows.items():
        print(f"| {name} | " + " | ".join(zs) + " |")


def _rows(fit: EllipsoidFit, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The residuals, their Jacobian (the points normalised as the fit's) and the factor that
    takes a normalised covariance to the points' unit."""
    xn, mu, s = _normalise(x)
    r, J = _res_jac(np.r_[_vec(fit.G * s), (fit.c - mu) / s], xn)
    unit = np.r_[np.full(6, 1.0 / s), np.full(3, s)]
    return r, J, np.outer(unit, unit)


def _hac(J: np.ndarray, r: np.ndarray, lag: int) -> np.ndarray:
    """Newey-West: ``(J'J)^-1 Omega (J'J)^-1``, Omega the Bartlett-kernel long-run variance of
    the scores ``J_t r_t`` (as overlapping sums of ``lag`` rows: the same weights)."""
    c = np.vstack([np.zeros((1, J.shape[1])), np.cumsum(J * r[:, None], axis=0)])
    s = c[lag:] - c[:-lag]
    inv = np.linalg.pinv(J.T @ J)
    return inv @ (s.T @ s / lag * len(r) / len(s)) @ inv


def _scores_jackknife(J: np.ndarray, r: np.ndarray, block: int) -> np.ndarray:
    """The block jackknife with each block's move ``(J'J)^-1 J_k' r_k`` (no leave-out normal
    matrix: the batch-means estimate of the scores' long-run variance)."""
    k = len(r) // block
    s = np.add.reduceat(J * r[:, None], np.arange(k) * block, axis=0)
    move = s @ np.linalg.pinv(J.T @ J)
    move -= move.mean(axis=0)
    return (k - 1) / k * move.T @ move


def alternatives(stream: Stream) -> dict[str, float]:
    """The halves' RMS z under each covariance."""
    mid = np.searchsorted(stream.t, (stream.t[0] + stream.t[-1]) / 2)
    halves = [stream.values[:mid], stream.values[mid:]]
    fits = [fit_ellipsoid(x) for x in halves]
    rows = [_rows(f, x) for f, x in zip(fits, halves)]
    covs: dict[str, list[np.ndarray]] = {}
    for (r, J, unit), f in zip(rows, fits):
        add = {"white (before)": f.cov_white}
        for lag in (100, 300, 1000):
            add[f"Newey-West, Bartlett, {lag} samples"] = _hac(J, r, lag) * unit
        add["block jackknife, scores only, c = 5"] = _scores_jackknife(
            J, r, max(1, min(correlation_window(r, 5.0)[0], len(r) // 10))) * unit
        for c in (5.0, 8.0):
            block = correlation_window(r, c)[0]
            add[f"block jackknife, leave-out normal matrix, c = {c:.0f}"] = \
                block_jackknife_cov(J, r, block)[0] * unit
        add["M8s (used)"] = f.cov
        for name, cov in add.items():
            covs.setdefault(name, []).append(cov)
    (da, db) = (_derived(f.params) for f in fits)
    out = {}
    for name, (ca, cb) in covs.items():
        sa, sb = (np.sqrt(np.diag(_derived_cov(f.params, c))) for f, c in zip(fits, (ca, cb)))
        out[name] = rms((da - db) / np.hypot(sa, sb))
    return out


if __name__ == "__main__":
    main(*sys.argv[1:])
