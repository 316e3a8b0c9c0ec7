"""Why the full-sphere recording's held-out norm residual is 0.85 % (the issue asks 0.8 %):
each candidate cause measured (bench/mag_full_sphere.md reports the figures).

    PYTHONPATH=. .venv/bin/python bench/mag_full_sphere.py [../shared/data]

- the two halves' fits side by side: hard iron, soft iron and field, with their standard
  errors (a sensor that keeps its parameters gives the same within a few of them);
- the second half judged by the first half's fit, split by whether the first half reached
  each sample's field direction (within 15 deg): extrapolation to directions not seen would
  show as a larger residual there;
- a hard iron drifting linearly in time, fitted on each half, extrapolated to the other;
- the axes sampled at different times (residual against ``u_i du_i/dt``), the sensor's
  averaging of a turning field (against ``|du/dt|^2``), the temperature;
- halves of interleaved 5 s pieces instead of the recording's two halves in time.
"""

from __future__ import annotations

import sys
from pathlib import Path

import h5py
import numpy as np

from imucal.numerics.ellipsoid import fit_ellipsoid, sym_from_vec


def _rms(r: np.ndarray) -> float:
    return float(100 * np.sqrt(np.mean(r * r)))


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _explained(r: np.ndarray, X: np.ndarray) -> float:
    """The RMS (%) of ``r`` left after a least-squares fit of ``X`` and a constant."""
    X = np.column_stack([X, np.ones(len(r))])
    return _rms(r - X @ np.linalg.lstsq(X, r, rcond=None)[0])


def _drift_fit(x: np.ndarray, t: np.ndarray, t0: float) -> np.ndarray:
    """``(g6, b, b')``: the ellipsoid with the hard iron ``b + b' (t - t0)``."""
    from scipy.optimize import least_squares

    return least_squares(lambda p: _drift_residuals(p, x, t, t0),
                         np.r_[fit_ellipsoid(x).params, np.zeros(3)], method="lm").x


def _drift_residuals(p: np.ndarray, x: np.ndarray, t: np.ndarray, t0: float) -> np.ndarray:
    return np.linalg.norm((x - p[6:9] - np.outer(t - t0, p[9:12])) @ sym_from_vec(p[:6]),
                          axis=1) - 1


def main(data: str = "../shared/data") -> None:
    folder = Path(data) / "sunsided_mpu6050_hmc5883l" / "full-sphere"
    with h5py.File(folder / "hmc5883l_compass.mat") as f:
        buf = f["compassBuffer"][:]
    with h5py.File(folder / "mpu6050_temperature.mat") as f:
        temp = f["temperatureBuffer"][:]
    t, x = buf[0], buf[1:].T.copy()
    cut = int(np.searchsorted(t, np.median(t)))
    a, b = x[:cut], x[cut:]
    fa, fb, full = fit_ellipsoid(a), fit_ellipsoid(b), fit_ellipsoid(x)
    F = float(np.linalg.det(full.G) ** (-1 / 3))
    r_full = full.residuals(x)
    held = np.r_[fb.residuals(a), fa.residuals(b)]
    print(f"in sample {_rms(r_full):.3f} %, held out {_rms(held):.3f} %")
    z_b = (fa.c - fb.c) / np.hypot(np.sqrt(np.diag(fa.cov))[6:9], np.sqrt(np.diag(fb.cov))[6:9])
    z_g = (fa.params[:6] - fb.params[:6]) / np.hypot(np.sqrt(np.diag(fa.cov))[:6],
                                                     np.sqrt(np.diag(fb.cov))[:6])
    dg = (fa.params[:6] - fb.params[:6]) / np.abs(full.params[:6]).max()
    print(f"halves' hard iron differ by {np.round(100 * (fa.c - fb.c) / F, 2).tolist()} % of "
          f"the field = {np.round(z_b, 0).tolist()} standard errors; G's six entries by "
          f"{np.round(100 * dg, 2).tolist()} % = {np.round(z_g, 0).tolist()} standard errors")
    ua, ub = _unit((a - full.c) @ full.G), _unit((b - full.c) @ full.G)
    near = np.concatenate([(ub[i:i + 500] @ ua[::2].T).max(axis=1) > np.cos(np.radians(15))
                           for i in range(0, len(ub), 500)])
    rb = fa.residuals(b)
    print(f"second half by the first's fit: {_rms(rb):.3f} % over all, {_rms(rb[near]):.3f} % "
          f"where the first half reached the direction ({near.mean():.0%} of the samples), "
          f"{_rms(rb[~near]):.3f} % where it did not")
    tm = float(t[cut])
    pa, pb = _drift_fit(a, t[:cut], tm), _drift_fit(b, t[cut:], tm)
    pf = _drift_fit(x, t, tm)
    drift_held = np.r_[_drift_residuals(pb, a, t[:cut], tm), _drift_residuals(pa, b, t[cut:], tm)]
    print(f"hard iron linear in time: in sample {_rms(_drift_residuals(pf, x, t, tm)):.3f} %, "
          f"held out {_rms(drift_held):.3f} %; drift per 100 s fitted on the first half "
          f"{np.round(100 * pa[9:12] / F * 100, 2).tolist()} % of the field, on the second "
          f"{np.round(100 * pb[9:12] / F * 100, 2).tolist()} %")
    u = (x - full.c) @ full.G
    du = np.gradient(u, t, axis=0)
    dtemp = np.interp(t, temp[0], temp[1]) - temp[1].mean()
    print(f"residual left after axes sampled apart (u_i du_i): {_explained(r_full, u * du):.3f} %;"
          f" after averaging a turning field (|du|^2): "
          f"{_explained(r_full, np.sum(du * du, axis=1)):.3f} %; after a hard iron linear in "
          f"temperature ({np.ptp(temp[1]):.2f} degC range): "
          f"{_explained(r_full, _unit(u) * dtemp[:, None]):.3f} %")
    odd = ((t - t[0]) // 5).astype(int) % 2 == 0
    f0, f1 = fit_ellipsoid(x[odd]), fit_ellipsoid(x[~odd])
    print(f"held out between interleaved 5 s pieces: "
          f"{_rms(np.r_[f1.residuals(x[odd]), f0.residuals(x[~odd])]):.3f} %")


if __name__ == "__main__":
    main(*sys.argv[1:])
