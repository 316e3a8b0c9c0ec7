"""The JSON and YAML exports' other triads (method.md §11) and temperature models (§12, M16):
everything calib.json holds of them that applying them needs, with the rule in words.

``temperature``: per sensor ``x = A diag(1 + k x_T) (x_raw - b(T))``, ``b(T) = b0 + sum_j
c[j] x_T^j``, ``x_T = clip(T, t_min, t_max) - t0``. ``triads``: each other triad's own pieces
of time (as the reference's ``pieces``), its rotation to the reference ``R`` (``u_ref = R u``,
M12) with its standard error, its gyroscope's own rotation from the turns (M14), its fit
against the reference (M15) and its temperature models, as calib.json has them.
"""

from __future__ import annotations

from imucal.io.exports.sections import Extras, TriadExport
from imucal.stages.temperature import BiasPolynomial

THERMAL_MODEL = ("x = A diag(1 + k x_T) (x_raw - b(T)), b(T) = b0 + sum_j c[j] x_T^j (j from "
                 "0), x_T = clip(T, t_min, t_max) - t0, T in deg C; A = T K of this model (the "
                 "accelerometer's fitted beside the polynomial, method.md M17), x_raw and b in "
                 "the raw unit, c[j] in the raw unit per deg C^j, k relative per deg C (zero: "
                 "the scales held constant)")


def thermal(fits: dict[str, BiasPolynomial]) -> dict:
    out: dict = {"model": THERMAL_MODEL}
    for sensor, f in fits.items():
        out[sensor] = {"t0": f.t0, "t_min": f.span[0], "t_max": f.span[1], "order": f.order,
                       "b0": f.b0.tolist(), "c": f.coefs.tolist(),
                       "k": [0.0, 0.0, 0.0] if f.scale_slope is None else f.scale_slope.tolist(),
                       "A": f.model.matrix.tolist(), "T": f.model.T.tolist(),
                       "K": f.model.K.tolist(), "notes": list(f.notes)}
    return out


def _triad(tri: TriadExport, pieces: list[dict]) -> dict:
    e = tri.entry
    return {"accelerometer": tri.name, "gyroscope": tri.gyro, "instance": tri.slot,
            "units": e.get("units"), "pieces": pieces,
            "rotation_to_reference": None if tri.R is None else tri.R.tolist(),
            "rotation_angle_deg": tri.angle_deg, "rotation_std_deg": e.get("rotation_std_deg"),
            "agreement_mg": e.get("agreement_mg"),
            "gyroscope_rotation": e.get("gyroscope_rotation"),
            "against_reference": e.get("against_reference"),
            "temperature": thermal(tri.temperature) if tri.temperature else None,
            "said": e.get("said") or []}


def extras_document(ext: Extras, pieces_of) -> dict:
    """The document's ``temperature`` and ``triads`` keys (only those it has);
    ``pieces_of(calibration)`` lays out a calibration's pieces as the reference's are."""
    out: dict = {}
    if ext.temperature:
        out["temperature"] = thermal(ext.temperature)
    if ext.triads:
        out["triads"] = {"reference": ext.reference, "instance": ext.slot,
                         "convention": ext.convention, "notes": list(ext.notes),
                         "triads": [_triad(t, pieces_of(t.calibration)) for t in ext.triads]}
    return out
