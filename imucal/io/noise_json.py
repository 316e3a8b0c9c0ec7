"""Noise figures as JSON-ready dicts, with their units: the ``noise`` key of calib.json and the
file ``imucal noise --out`` writes."""

from __future__ import annotations

import numpy as np

from imucal.io.json_numbers import json_number as _f
from imucal.stages.noise import AXES, NoiseReport, SensorNoise

METHOD = ("overlapping Allan deviation at octave taus (IEEE Std 952-1997 Annex C); fit "
          "avar(tau) = N^2/tau + c + K^2 tau/3 by non-negative least squares: N (white noise "
          "density: velocity / angle random walk) is the slope -1/2 line at tau = 1 s, K (rate "
          "random walk) the slope +1/2 line at tau = 3 s; bias instability = minimum deviation "
          "/ 0.664. *_rel_err: about one standard error, relative. null: not determined by "
          "these data (see notes)")


def sensor_dict(sn: SensorNoise) -> dict:
    taus = sn.taus
    return {
        "unit": sn.unit,
        "rate_hz": _f(sn.rate_hz),
        "white_noise_density": [_f(v) for v in sn.per_axis("white")],
        "white_noise_density_unit": sn.white_unit,
        "white_noise_density_rel_err": [_f(v) for v in sn.per_axis("white_rel_err")],
        "bias_instability": [_f(v) for v in sn.per_axis("bias_instability")],
        "bias_instability_unit": sn.unit,
        "bias_instability_tau_s": [_f(f.tau_min_adev) if f.bias_instability is not None
                                   else None for f in sn.fits],
        "random_walk": [_f(v) for v in sn.per_axis("random_walk")],
        "random_walk_unit": sn.random_walk_unit,
        "random_walk_rel_err": [_f(v) for v in sn.per_axis("random_walk_rel_err")],
        "fit_from_tau_s": [_f(f.fit_from_tau) for f in sn.fits],
        "allan_deviation": {"tau_s": [_f(t) for t in taus],
                            "unit": sn.unit,
                            **{a: [_f(v) for v in np.sqrt(sn.curve.avar[:, i])]
                               for i, a in enumerate(AXES)},
                            "terms": [int(v) for v in sn.curve.terms]},
        "samples": int(sn.curve.n),
        "notes": sn.notes(),
    }


def noise_to_dict(report: NoiseReport | None) -> dict | None:
    if report is None:
        return None
    return {
        "source": report.source,
        "method": METHOD,
        "accelerometer": None if report.accelerometer is None else
        sensor_dict(report.accelerometer),
        "gyroscope": None if report.gyroscope is None else sensor_dict(report.gyroscope),
        "notes": list(report.notes),
    }


KALIBR_UNITS = {
    "accelerometer_noise_density": "m/s^2/sqrt(Hz)",
    "accelerometer_random_walk": "m/s^3/sqrt(Hz)",
    "gyroscope_noise_density": "rad/s/sqrt(Hz)",
    "gyroscope_random_walk": "rad/s^2/sqrt(Hz)",
    "update_rate": "Hz",
}


def _largest(values: list | None) -> float | None:
    if not values or any(v is None for v in values):
        return None
    return max(float(v) for v in values)


def kalibr_block(noise: dict | None) -> tuple[dict[str, float | None], list[str]]:
    """Kalibr's imu.yaml noise block (Kalibr wiki, "IMU Noise Model") from a ``noise`` dict
    (:func:`noise_to_dict`): continuous-time noise densities and bias random walks in SI units
    (:data:`KALIBR_UNITS`), one value per sensor, the largest of the three axes (Kalibr models
    the axes alike; the largest is the safe one). A figure the data do not determine is
    ``None``, with the reason in the notes. An accelerometer in g is converted with
    g_n = 9.80665 m/s^2 (a unit, not the local gravity).
    """
    from imucal.session import STANDARD_GRAVITY

    scale = {"g": STANDARD_GRAVITY, "m/s^2": 1.0, "rad/s": 1.0}
    block: dict[str, float | None] = {}
    notes: list[str] = []
    rates = []
    for key in ("accelerometer", "gyroscope"):
        sn = (noise or {}).get(key)
        nd = rw = None
        if not sn:
            notes.append(f"{key}: no noise figures")
        elif sn.get("unit") not in scale:
            notes.append(f"{key}: measured in {sn.get('unit')}, not a physical unit: give the "
                         "calibration (--calibration) to measure calibrated signals")
        else:
            f = scale[sn["unit"]]
            nd, rw = _largest(sn.get("white_noise_density")), _largest(sn.get("random_walk"))
            nd = None if nd is None else nd * f
            rw = None if rw is None else rw * f
            if sn.get("rate_hz"):
                rates.append(float(sn["rate_hz"]))
            notes += [f"{key}: {w}" for w in sn.get("notes", [])]
        block[f"{key}_noise_density"] = nd
        block[f"{key}_random_walk"] = rw
    block["update_rate"] = max(rates) if rates else None
    return block, notes
