"""imucal apply with a calibration of several triads or temperature models (method.md §11,
§12, M18): every triad's calibrated columns in one frame, the combined accelerometer, the
temperature, and what was done said. Kept apart from commands.py (its own idea)."""

from __future__ import annotations

from pathlib import Path
from typing import Any


def applied(cal: Any, calibration: Path, session: Any, reference: str | None
            ) -> tuple[Any, list[str]]:
    """The calibrated signals of ``session`` (``cal.apply``'s, with the other triads' columns
    beside them where the file holds triads or temperature models) and the notes to print."""
    from imucal.errors import ImucalError
    from imucal.io.triads_calibration import load_triads
    from imucal.stages.apply import CalibratedSignals

    triads = load_triads(str(calibration), cal)
    if triads is None:
        if reference is not None:
            raise ImucalError("--reference chooses among the calibration's triads; it holds one "
                              "(calibrate with --all-imus or --triad)", source=str(calibration),
                              field="--reference")
        return cal.apply(session), []
    # The file's own models on the pair only where its reference is the pair (after calibrate
    # --reference a2 the pair is one of the file's other triads).
    base = cal.apply(session) if triads.reference_is_pair(session) else None
    out = triads.apply(session, reference, base=base)
    t_mag = mag = None
    stream = session.magnetometer
    if base is not None:
        t_mag, mag = base.t_mag, base.mag
    elif cal.mag is not None and stream is not None:  # M8 is in the file's reference's frame
        t_mag, mag = stream.t, cal.mag.apply(stream.values)
    if mag is not None:
        mag = mag @ out.frame.T
    signals = CalibratedSignals(t_acc=session.t_acc, acc=out.acc,
                                t_gyro=None if out.gyro is None else session.t_gyro,
                                gyro=out.gyro, acc_unit=out.acc_unit, t_mag=t_mag, mag=mag,
                                columns=out.columns)
    written = [c for c in out.columns if c[-1:] == "x" and c[:-1] + "y" in out.columns]
    head = ", ".join(f"{c[:-1]}x, {c[:-1]}y, {c[:-1]}z" for c in written) or "no other triad"
    head += "" if "temp" not in out.columns else "; the temperature as temp"
    return signals, [f"triads          {head}"] + [f"  - {n}" for n in out.notes]


def notes_applied(notes: list[str] | tuple[str, ...], columns: tuple[str, ...] | None
                  ) -> list[str]:
    """The loader's notes with those of a2x…, g2x…, temp made true where the output holds
    them calibrated (the other triads' columns, the temperature passed through)."""
    from imucal.warning import calibrated_note

    have = set(columns or ())
    out = []
    for n in notes:
        for c in have:
            if c == "temp":
                n = calibrated_note(n, "temp", "passed through as temp")
            elif c.endswith("x") and {c[:-1] + "y", c[:-1] + "z"} <= have:
                n = calibrated_note(n, c[:-1], f"calibrated, in the output's frame as {c}…")
        out.append(n)
    return out


def stated_ranges(ranges: list[str] | None, triads: bool) -> dict[str, float]:
    """``--range NAME=G`` as {name: g}; a usage error for a malformed one, or without the
    other triads to pair (--all-imus, --triad)."""
    import math

    from imucal.cli.options import usage_error

    out: dict[str, float] = {}
    for item in ranges or ():
        name, _, value = item.partition("=")
        try:
            g = float(value)
        except ValueError:
            g = math.nan
        if not name.strip() or not (math.isfinite(g) and g > 0):
            raise usage_error(f"expected NAME=G (a triad's range in g, > 0), got {item!r}",
                              "'--range'")
        out[name.strip()] = g
    if out and not triads:
        raise usage_error("--range pairs the reference with another triad: give --all-imus or "
                          "--triad", "'--range'")
    return out
