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
"""

from __future__ import annotations

import sys
from itertools import combinations
from pathlib import Path

import h5py
import numpy as np

from imucal.stages.mag import MagFit, MagUnfit, calibrate_magnetometer
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
    print("| recording | pieces | design effect (block, samples) | RMS z white (before) | "
          "RMS z now | max abs z now | std of b now / before |")
    print("|---|---:|---|---:|---:|---:|---:|")
    for stream in recordings(Path(data)):
        whole = calibrate_magnetometer(stream)
        for k in (2, 3):
            fits = pieces(stream, k)
            now, white = z_scores(fits)
            de = ", ".join(f"{f.se_design_effect:.0f} ({f.se_block})" if f else "not fitted"
                           for f in fits)
            print(f"| {stream.instance} | {k} | {de} | {rms(white):.1f} | {rms(now):.2f} | "
                  f"{np.abs(now).max():.1f} | {np.sqrt(whole.se_design_effect):.1f}x "
                  f"(whole) |")


if __name__ == "__main__":
    main(*sys.argv[1:])
