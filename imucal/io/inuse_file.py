"""A calibration file read for a check in use, and the refreshed one written (method.md §10).

Reading takes the calibration (checked as ``imucal apply`` checks it) and the figures the
check holds it to: the held-out still-norm error (``quality.static_norm_rms_mg``) and the
accelerometer's white noise density (``noise.accelerometer``). Writing copies the file and
changes only the refreshed numbers of the checked segment, so every other parameter stays as
stored to the last digit, and adds a ``refresh`` section: from which recording, what changed by
how much, what was kept and why."""

from __future__ import annotations

import copy
import hashlib
import json
import os
from typing import Any

import numpy as np

from imucal.errors import ImucalError
from imucal.inuse.check import Stored
from imucal.inuse.refresh import Refresh
from imucal.io.atomic import write_text_atomic
from imucal.io.calibration_file import _read_json, calibration_from_dict, migrate
from imucal.stages.apply import Calibration


def read_for_check(path: str | os.PathLike) -> tuple[Calibration, Stored, dict[str, Any]]:
    """The calibration at ``path``, its stored figures and the file's (migrated) contents."""
    data = migrate(_read_json(path), source=str(path))
    cal = calibration_from_dict(data, source=str(path))
    return cal, stored_figures(data, str(path)), data


def stored_figures(data: dict, source: str = "calibration") -> Stored:
    """The held-out still-norm error (else the in-sample one) and the accelerometer's mean
    white noise density over its axes; None where the file has none (a calibration written
    without a run: ``imucal`` says what it assumed instead)."""
    norm = None
    q = data.get("quality")
    if isinstance(q, dict) and isinstance(q.get("static_norm_rms_mg"), dict):
        s = q["static_norm_rms_mg"]
        norm = _positive(s.get("cross_validated"), source, "quality.static_norm_rms_mg")
        if norm is None:
            norm = _positive(s.get("after"), source, "quality.static_norm_rms_mg.after")
    density = None
    noise = data.get("noise")
    acc = noise.get("accelerometer") if isinstance(noise, dict) else None
    if isinstance(acc, dict) and isinstance(acc.get("white_noise_density"), list):
        values = [_positive(v, source, "noise.accelerometer.white_noise_density")
                  for v in acc["white_noise_density"]]
        values = [v for v in values if v is not None]
        density = float(np.mean(values)) if values else None
    return Stored(static_norm_mg=norm, acc_noise_density=density)


def _positive(x: Any, source: str, field: str) -> float | None:
    if x is None:
        return None
    if isinstance(x, bool) or not isinstance(x, (int, float)) or not np.isfinite(x) or x < 0:
        raise ImucalError(f"expected a number >= 0, got {x!r}", source=source, field=field)
    return float(x)


def file_sha256(path: str | os.PathLike) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def refreshed_dict(data: dict, refresh: Refresh, *, calibration: str, calibration_sha256: str,
                   recording: str, recording_sha256: str) -> dict:
    """``data`` with the checked (last) segment's refreshed numbers put in and the others
    dropped (the refreshed calibration describes the device now), and its ``refresh``
    provenance. Every number not refreshed is the stored one, untouched."""
    out = copy.deepcopy(data)
    segments = out["segments"]
    seg = segments[-1]
    for c in refresh.changed:
        part = seg["accelerometer" if c.sensor == "accelerometer" else "gyroscope"]
        i = "xyz".index(c.parameter[-1])
        part["b" if c.parameter.startswith("b") else "K"][i] = c.value
        if isinstance(part.get("std"), dict):
            part["std"][c.parameter] = c.std_error
    out["segments"] = [seg]
    out["refresh"] = {
        "method": "method.md §10 (M9-M11): still moments of everyday use; each refreshed "
                  "parameter pulled towards its stored value by a prior",
        "calibration": {"file": calibration, "sha256": calibration_sha256},
        "recording": {"file": recording, "sha256": recording_sha256},
        "segment": f"the last of {len(segments)}" if len(segments) > 1 else "the only one",
        **refresh.to_dict(),
        "note": "quality, noise, detector and the other sections are those of the stored "
                "calibration's own run"}
    return out


def write_refreshed(path: str | os.PathLike, data: dict) -> None:
    write_text_atomic(path, json.dumps(data, indent=2, allow_nan=False) + "\n")

