"""The heading of the BROAD trials' magnetometer, raw and calibrated by imucal's own fit of the
trial itself (M8, imucal.stages.mag), judged against the optical reference (issue 23).

    PYTHONPATH=. .venv/bin/python bench/mag_broad.py [../shared/data/broad]

For each trial: the field (raw, and calibrated ``M (m_raw - b)``: no ``R_am``, these trials
give too few still blocks for it, and the IMU's magnetometer shares the IMU's frame) turned
into the optical East-North-Up frame by ``opt_quat`` (samples where it is defined); its
horizontal direction ``atan2(E, N)`` is the heading, which a constant field keeps over the
whole trial. Reported: the RMS of its deviation from the circular mean (deg), the 99th
percentile of the absolute deviation, the calibrated-minus-raw RMS with a jackknife standard
error over 20 contiguous pieces of the trial (the samples are strongly correlated in time),
and the same at the magnetometer-to-reference delay that minimises the raw RMS (whole
samples, -10..10). A trial whose magnetometer imucal cannot calibrate is said, not figured.
"""

from __future__ import annotations

import sys
from pathlib import Path

import h5py
import numpy as np

from imucal.numerics import quaternion as quat
from imucal.numerics.windows import block_means, runs_of_true
from imucal.stages.mag import MagUnfit, calibrate_magnetometer
from imucal.streams import Stream

PIECES = 20


def heading_deviation_deg(m_body: np.ndarray, q: np.ndarray) -> np.ndarray:
    """(N,) each sample's heading of the field ``m_body`` (N, 3) turned by ``q`` (N, 4,
    body to East-North-Up) from the circular mean heading, deg."""
    w = np.einsum("kij,kj->ki", quat.to_matrix(q), m_body)
    psi = np.arctan2(w[:, 0], w[:, 1])
    mean = np.angle(np.mean(np.exp(1j * psi)))
    return np.degrees(np.angle(np.exp(1j * (psi - mean))))


def rms_difference(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """``rms(b) - rms(a)`` and its jackknife standard error over PIECES contiguous pieces."""
    a2, b2 = a * a, b * b
    full = float(np.sqrt(b2.mean()) - np.sqrt(a2.mean()))
    parts = np.array_split(np.arange(len(a)), PIECES)
    jk = []
    for p in parts:
        keep = np.ones(len(a), bool)
        keep[p] = False
        jk.append(np.sqrt(b2[keep].mean()) - np.sqrt(a2[keep].mean()))
    jk = np.array(jk)
    return full, float(np.sqrt((PIECES - 1) / PIECES * np.sum((jk - jk.mean()) ** 2)))


def trial(path: Path) -> dict:
    with h5py.File(path) as f:
        mag, q, acc = f["imu_mag"][:], f["opt_quat"][:], f["imu_acc"][:]
        still = ~f["movement"][:].astype(bool)
        rate = float(f.attrs["sampling_rate"])
    t = np.arange(len(mag)) / rate
    # the still periods the file marks (longer than 1 s), as the magnetometer's stage takes
    # them: a step of the field inside one is a magnet that moved
    runs = runs_of_true(still)
    runs = runs[runs[:, 1] - runs[:, 0] > rate]
    blocks = np.column_stack([t[runs[:, 0]], t[runs[:, 1] - 1]])
    ok = np.isfinite(q).all(axis=1)
    out = {"trial": path.stem, "samples": len(mag), "reference": int(ok.sum())}
    raw = heading_deviation_deg(mag[ok], q[ok])
    out["raw_rms"], out["raw_p99"] = float(np.sqrt(np.mean(raw ** 2))), float(
        np.percentile(np.abs(raw), 99))
    try:
        fit = calibrate_magnetometer(Stream("mag", "imu_mag", t, mag, "uT", str(path)), blocks,
                                     block_means(acc, runs))
    except MagUnfit as e:
        out["unfit"] = e.message
        out["disturbances"] = [d.text() for d in e.disturbances]
        return out
    cal_all = fit.apply(mag)
    cal = heading_deviation_deg(cal_all[ok], q[ok])
    out["cal_rms"], out["cal_p99"] = float(np.sqrt(np.mean(cal ** 2))), float(
        np.percentile(np.abs(cal), 99))
    out["diff"], out["diff_se"] = rms_difference(raw, cal)
    lags = range(-10, 11)
    best = min(lags, key=lambda k: np.mean(heading_deviation_deg(
        np.roll(mag, k, axis=0)[ok], q[ok]) ** 2))
    r = heading_deviation_deg(np.roll(mag, best, axis=0)[ok], q[ok])
    c = heading_deviation_deg(np.roll(cal_all, best, axis=0)[ok], q[ok])
    out |= {"lag": best, "lag_ms": 1000 * -best / rate,
            "lag_raw_rms": float(np.sqrt(np.mean(r * r))),
            "lag_cal_rms": float(np.sqrt(np.mean(c * c)))}
    out["lag_diff"], out["lag_diff_se"] = rms_difference(r, c)
    qq = fit.quality
    out |= {"field": fit.field, "b": fit.b.tolist(),
            "M_off": float(np.abs(fit.M - np.eye(3)).max()),
            "norm_in": qq.norm_rms_pct, "norm_held_out": qq.norm_rms_held_out_pct,
            "coverage": qq.coverage, "disturbances": [d.text() for d in fit.disturbances],
            "soft_iron": fit.soft_iron}
    return out


def main(folder: str = "../shared/data/broad") -> None:
    rows = [trial(p) for p in sorted(Path(folder).glob("*.hdf5"))]
    print("| trial | raw RMS deg | calibrated RMS deg | calibrated - raw (SE) | raw p99 | "
          "calibrated p99 | at the best delay: raw, calibrated, difference (SE) |")
    print("|---|---:|---:|---:|---:|---:|---|")
    for r in rows:
        if "unfit" in r:
            print(f"| {r['trial']} | {r['raw_rms']:.2f} | not fitted | | {r['raw_p99']:.1f} "
                  f"| | |")
            continue
        print(f"| {r['trial']} | {r['raw_rms']:.2f} | {r['cal_rms']:.2f} | "
              f"{r['diff']:+.2f} ({r['diff_se']:.2f}) | {r['raw_p99']:.1f} | "
              f"{r['cal_p99']:.1f} | {r['lag_ms']:+.0f} ms: {r['lag_raw_rms']:.2f}, "
              f"{r['lag_cal_rms']:.2f}, {r['lag_diff']:+.2f} ({r['lag_diff_se']:.2f}) |")
    print()
    for r in rows:
        if "unfit" in r:
            print(f"- {r['trial']}: not calibrated: {r['unfit']}; found: "
                  f"{'; '.join(r['disturbances'])}")
        else:
            print(f"- {r['trial']}: field {r['field']:.2f} uT, b {np.round(r['b'], 2).tolist()} "
                  f"uT, |M - I| at most {r['M_off']:.3f}, norm RMS {r['norm_in']:.2f} % in "
                  f"sample, {r['norm_held_out']:.2f} % held out, coverage "
                  f"{r['coverage']:.0%}, disturbances: {len(r['disturbances'])}")


if __name__ == "__main__":
    main(*sys.argv[1:])
