"""``imucal noise``: the noise figures of a long still recording, streamed chunk by chunk.

Memory: one chunk of the file (:mod:`imucal.io.chunks`) plus the two Allan accumulators of
:class:`imucal.stages.noise.StreamingNoise` (a few KB: per octave lag, at most 2 x 64 running
sums per axis), whatever the recording's length.
"""

from __future__ import annotations

import os
from typing import Any

from imucal.errors import ImucalError
from imucal.io.chunks import CHUNK_BYTES, continuous_time, iter_chunks
from imucal.io.readers import display_name
from imucal.stages.apply import Calibration
from imucal.stages.noise import MAX_MOTION, NoiseReport, StreamingNoise


def measure_noise(path: str | os.PathLike, *, calibration: Calibration | None = None,
                  chunk_bytes: int = CHUNK_BYTES, **load_kw: Any) -> NoiseReport:
    """Noise figures of the recording at ``path`` (``load_kw``: :func:`load_session`'s
    options). With a ``calibration``, the calibrated signals are measured (g or m/s^2, rad/s);
    without, the raw ones in the file's units."""
    from pathlib import Path

    names = [display_name(Path(path))]
    if load_kw.get("gyro_path") is not None:
        names.append(display_name(Path(load_kw["gyro_path"])))
    stream: StreamingNoise | None = None
    last: dict[str, float | None] = {"accelerometer": None, "gyroscope": None}
    chunks = 0
    notes: list[str] = []
    for sess in iter_chunks(path, chunk_bytes=chunk_bytes, **load_kw):
        chunks += 1
        if stream is None:
            notes += list(sess.notes)
            _check_gyro_unit(sess.notes, load_kw.get("gyro_unit", "auto"), sess.source,
                             sess.has_gyro)
            if calibration is not None:
                acc_unit, gyro_unit = calibration.acc_unit, "rad/s"
            else:
                acc_unit, gyro_unit = sess.acc_unit, sess.gyro_unit
            stream = StreamingNoise(acc_unit, gyro_unit if sess.has_gyro else None)
        if calibration is not None:
            sig = calibration.apply(sess)
            acc, gyro = sig.acc, sig.gyro
        else:
            acc, gyro = sess.acc, sess.gyro if sess.has_gyro else None
        t = continuous_time(sess.t_acc, last["accelerometer"])
        chunk = {"accelerometer": (t, acc)}
        last["accelerometer"] = float(t[-1])
        if gyro is not None and sess.t_gyro is not None:
            tg = continuous_time(sess.t_gyro, last["gyroscope"])
            chunk["gyroscope"] = (tg, gyro)
            last["gyroscope"] = float(tg[-1])
        stream.feed(chunk)  # what is not still is left out
    if stream is None:
        raise ImucalError("no samples", source=names[0])
    if stream.moving_fraction() > MAX_MOTION:
        raise ImucalError(f"is mostly motion, not a still recording: "
                          f"{100 * stream.moving_fraction():.3g} % of the samples are not still "
                          "(beyond 8 noise sigmas of their second's median); the noise figures "
                          "need the sensor at rest", source=names[0])
    what = "calibrated" if calibration is not None else "raw"
    source = (f"{' + '.join(names)}: still recording, {what} signals, read in {chunks} "
              f"chunk{'s' if chunks != 1 else ''}; overlapping Allan deviation at octave taus")
    report = stream.report(source)
    return NoiseReport(accelerometer=report.accelerometer, gyroscope=report.gyroscope,
                       source=report.source, notes=tuple(notes) + report.notes,
                       still=report.still)


def _check_gyro_unit(notes: tuple[str, ...], given: str, source: str, has_gyro: bool) -> None:
    """A still gyroscope reads near zero in rad/s and in deg/s alike: the loader's guess from
    the signal's size cannot tell them apart, and a wrong one scales every figure by 57."""
    if has_gyro and given == "auto" and any(n.startswith("gyroscope unit guessed") for n in notes):
        raise ImucalError("a still recording cannot tell rad/s from deg/s (the rates are near "
                          "zero either way); give --gyro-unit rad/s, deg/s or counts",
                          source=source, field="gyroscope unit")
