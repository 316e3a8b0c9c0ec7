"""``imucal synth --activity``: a recording of everyday use (method.md §10) with known drift, its
truth, and the calibration before the drift, for ``imucal check`` and ``imucal refresh``. Kept
apart from commands.py (synth's other sessions) and inuse.py (the commands that take these
files): its own small idea, light to import (numpy and the core inside the function)."""

from __future__ import annotations

from pathlib import Path

from imucal.cli.options import parse_triple
from imucal.cli.outputs import Progress, check_outputs


def synth_everyday(out: Path, truth: Path | None, activity: str, *, minutes: float | None,
                   seed: int, acc_rate: float, acc_noise: float, gyro_noise: float,
                   drifts: tuple[str | None, str | None, str | None], verbose: bool) -> None:
    """``imucal synth --activity``: a recording of everyday use (method.md §10), its truth,
    and the calibration before the drift (OUT.calib.json, with the sensor's noise density),
    which ``imucal check`` and ``imucal refresh`` take."""
    import numpy as np

    gyro_b = np.radians(parse_triple(drifts[0], "--drift-gyro-bias"))
    acc_b = np.array(parse_triple(drifts[1], "--drift-acc-bias")) * 1e-3
    acc_s = np.array(parse_triple(drifts[2], "--drift-acc-scale")) * 1e-2
    truth = truth if truth is not None else out.with_name(out.name + ".truth.json")
    calib = out.with_name(out.name + ".calib.json")
    check_outputs([out, truth, calib], [])
    from imucal.inuse.everyday import Drift, make_everyday
    from imucal.io.atomic import write_text_atomic
    from imucal.io.calibration_file import calibration_to_dict
    from imucal.io.export import write_session_csv, write_session_mat
    from imucal.stages.apply import Calibration, SegmentModels

    progress = Progress(verbose)
    with progress.stage(f"generating {activity}"):
        session, tr = make_everyday(activity, minutes=10.0 if minutes is None else minutes,
                                    seed=seed, rate=acc_rate, acc_noise=acc_noise,
                                    gyro_noise=gyro_noise,
                                    drift=Drift(gyro_bias=gyro_b, acc_bias=acc_b,
                                                acc_scale=acc_s))
    stored = Calibration(segments=(SegmentModels(0.0, 0.0, tr.stored_acc, tr.stored_gyro),),
                         acc_unit_raw="g", acc_unit="g", g=1.0, gyro_unit_raw="rad/s")
    density = acc_noise / float(np.sqrt(acc_rate))
    cal = calibration_to_dict(stored) | {"noise": {"accelerometer": {
        "unit": "g", "white_noise_density": [density] * 3,
        "note": "the synthetic sensor's own (imucal synth --activity)"}}}
    import json

    with progress.stage(f"writing {out}"):
        if out.suffix.lower() == ".csv":
            write_session_csv(out, session)
        else:
            write_session_mat(out, session)
        write_text_atomic(truth, json.dumps(tr.to_dict(), indent=2) + "\n")
        write_text_atomic(calib, json.dumps(cal, indent=2) + "\n")
    print(f"session         {activity}, {session.duration:.1f} s, {len(tr.still)} still "
          f"stretches, {len(tr.taps)} taps, accelerometer and gyroscope at {acc_rate:g} Hz\n"
          f"wrote {out}\nwrote {truth}\nwrote {calib} (the calibration before the drift)")
