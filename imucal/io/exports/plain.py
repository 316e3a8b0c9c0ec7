"""The whole calibration as plain JSON or YAML with units, for any other tool.

Per sensor and piece of time: ``x = A (x_raw - b)`` with ``A = T K`` multiplied out (and T, K
given too), ``x_raw`` in the raw unit, ``x`` in the calibrated unit. The pieces are imucal's
(method.md §2): each segment over its closed [t_start, t_end] (the first from the start of
time, the last to its end), and between two segments, over the open gap, the parameter-wise
mean of the two. The noise figures go along with their units, and a calibrated magnetometer
(M8) its ``magnetometer`` entry: ``m = A (m_raw - b)``, ``A = R_am M``, with M, b, R_am.
Other triads and temperature models (method.md §11, §12), where calib.json has them:
``triads`` and ``temperature`` (:mod:`imucal.io.exports.plain_triads`).
Nothing is lost: doubles are written with 17 significant digits (JSON) or their shortest exact
form (YAML).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from imucal.io.exports.common import Exported, ExportInput, piece_models
from imucal.io.exports.mag import plain_mag
from imucal.io.exports.plain_triads import extras_document
from imucal.io.exports.yaml_text import comment_block, dump
from imucal.io.noise_json import kalibr_block
from imucal.models import SensorModel
from imucal.stages.apply import SegmentModels

FORMAT = "imucal-export"
FORMAT_VERSION = 1
MODEL = ("x = A (x_raw - b), A = T K (T misalignment, K = diag(scale)), per sensor and piece of "
         "time (method.md M2, M4). A piece 'segment' holds for t_start <= t <= t_end, a piece "
         "'between' for t_start < t < t_end; the first piece also before its t_start, the last "
         "also after its t_end (t in seconds on the calibration session's clock).")


def _num(x: float) -> float | None:
    return float(x) if math.isfinite(float(x)) else None


def _model(m: SensorModel) -> dict:
    return {"A": m.matrix.tolist(), "b": m.b.tolist(), "T": m.T.tolist(), "K": m.K.tolist()}


def document(inp: ExportInput, segment: int | None) -> dict:
    cal = inp.calibration
    segs = cal.segments
    if segment is not None:
        _, one = inp.segment(segment, "this format")
        segs = (one,)
    pieces = _pieces(segs)
    gyro = "gyroscope" in pieces[0]
    kalibr, _ = kalibr_block(inp.noise)
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "model": MODEL,
        "units": {"accelerometer_raw": cal.acc_unit_raw, "accelerometer": cal.acc_unit,
                  "g": cal.g, "gyroscope_raw": cal.gyro_unit_raw if gyro else None,
                  "gyroscope": "rad/s" if gyro else None, "time": "s",
                  "note": "a gyroscope recorded in deg/s was converted to rad/s before the fit: "
                          "its raw unit here is rad/s"},
        "pieces": pieces,
        "noise": _noise_summary(inp.noise),
        "kalibr_noise": kalibr,
        "source": {"calibration": inp.path.name, **(inp.source or {})},
    } | ({"magnetometer": plain_mag(inp.magnetometer)} if inp.magnetometer is not None else {}
         ) | (extras_document(inp.extras, lambda cal: _pieces(cal.segments))
              if inp.extras is not None else {})


def _pieces(segs: tuple[SegmentModels, ...]) -> list[dict]:
    pieces = []
    acc = piece_models(segs, "acc")
    gyro = piece_models(segs, "gyro") if all(s.gyro is not None for s in segs) else None
    for i, (kind, t0, t1, m) in enumerate(acc):
        assert m is not None
        piece = {"kind": kind, "t_start": _num(t0), "t_end": _num(t1),
                 "accelerometer": _model(m)}
        if gyro is not None:
            gm = gyro[i][3]
            assert gm is not None
            piece["gyroscope"] = _model(gm)
        pieces.append(piece)
    return pieces


def _noise_summary(noise: dict | None) -> dict | None:
    if not noise:
        return None
    out = {}
    for key in ("accelerometer", "gyroscope"):
        sn = noise.get(key)
        if not sn:
            continue
        out[key] = {k: sn.get(k) for k in (
            "unit", "rate_hz", "white_noise_density", "white_noise_density_unit",
            "bias_instability", "bias_instability_unit", "random_walk", "random_walk_unit")}
    out["source"] = noise.get("source")
    return out


def to_json(inp: ExportInput, out: Path, segment: int | None) -> Exported:
    text = json.dumps(document(inp, segment), indent=2, allow_nan=False) + "\n"
    return Exported(files=[(out, text)], notes=_notes(inp, segment))


def to_yaml(inp: ExportInput, out: Path, segment: int | None) -> Exported:
    head = comment_block(["imucal calibration export (YAML 1.1/1.2)", *inp.header_lines()])
    return Exported(files=[(out, head + dump(document(inp, segment)))],
                    notes=_notes(inp, segment))


def _notes(inp: ExportInput, segment: int | None) -> list[str]:
    n = len(inp.calibration.segments)
    which = f"segment {segment} of {n}" if segment is not None else f"all {n} segment(s)"
    return [f"the full model ({which}), with units; exact"] + (
        [f"magnetometer: M, b, R_am and A = R_am M, in {inp.magnetometer.unit}; exact"]
        if inp.magnetometer is not None else []) + _extras_notes(inp)


def _extras_notes(inp: ExportInput) -> list[str]:
    ext = inp.extras
    if ext is None:
        return []
    said = [f"temperature: {', '.join(ext.temperature)} bias in temperature; exact"
            ] if ext.temperature else []
    if ext.triads:
        said.append(f"{len(ext.triads)} other triad(s): own pieces, rotation to the reference, "
                    "temperature; exact")
    return said + list(ext.notes)
