"""Writing sessions and calibrated signals: .mat (v5), Parquet and CSV, always atomically."""

from __future__ import annotations

import io
import json
import os
from pathlib import Path

import numpy as np

from imucal.errors import ImucalError
from imucal.io.atomic import write_atomic, write_text_atomic
from imucal.session import Session
from imucal.stages.apply import CalibratedSignals
from imucal.synth import Truth

FORMATS = {".parquet": "parquet", ".pq": "parquet", ".csv": "csv", ".mat": "mat"}


def output_format(path: str | os.PathLike) -> str:
    fmt = FORMATS.get(Path(path).suffix.lower())
    if fmt is None:
        raise ImucalError("unknown output format; expected a name ending in .parquet, .csv or "
                          ".mat", source=str(path), field="output path")
    return fmt


def write_session_mat(path: str | os.PathLike, session: Session, gyro_unit: str | None = None
                      ) -> None:
    """A session as MATLAB v5 named variables ``acc``, ``gyro``, ``t_acc``, ``t_gyro``;
    ``gyro_unit="deg/s"`` writes a rad/s gyroscope in deg/s (the loader converts it back)."""
    from scipy.io import savemat

    data = {"acc": session.acc, "t_acc": session.t_acc}
    if session.has_gyro:
        gyro = session.gyro
        if gyro_unit == "deg/s":
            if session.gyro_unit != "rad/s":
                raise ValueError(f"cannot write a gyroscope in {session.gyro_unit} as deg/s")
            gyro = np.rad2deg(gyro)
        data |= {"gyro": gyro, "t_gyro": session.t_gyro}

    def _w(tmp: Path) -> None:
        with open(tmp, "wb") as f:
            savemat(f, data, do_compression=True, oned_as="column")

    write_atomic(path, _w)


def write_session_csv(path: str | os.PathLike, session: Session, gyro_unit: str | None = None,
                      *, preamble: dict[str, float] | None = None,
                      cut_last_line: bool = False, mag: bool = False,
                      triads: bool = False) -> None:
    """A session as one CSV table, as a logger writes it: ``t,ax,ay,az,gx,gy,gz``; with a
    ``preamble`` of ``key,value`` lines above the header and no time column instead (the rate
    is in the preamble); ``cut_last_line`` ends the file in the middle of its last row, as a
    logger killed mid-write leaves it; ``mag``: the session's first magnetometer in columns
    ``mx,my,mz`` on the rows of its timestamps (each one an accelerometer timestamp), empty
    on the others; ``triads``: the other accelerometer and gyroscope triads (``a2x…``,
    ``g2x…``, each on the accelerometer's timestamps) and a temperature stream (``temp``,
    interpolated onto them). Numbers are written to round-trip exactly."""
    if not session.has_gyro or not np.array_equal(session.t_acc, session.t_gyro):
        raise ValueError("a CSV session needs the gyroscope at the accelerometer's timestamps")
    gyro = session.gyro
    if gyro_unit == "deg/s":
        gyro = np.rad2deg(gyro)
    columns = [session.acc, gyro]
    names = ["ax", "ay", "az", "gx", "gy", "gz"]
    if mag:
        stream = session.magnetometer
        rows = np.searchsorted(session.t_acc, stream.t)
        rows = np.minimum(rows, len(session.t_acc) - 1)
        if not np.allclose(session.t_acc[rows], stream.t, rtol=0, atol=1e-9):
            raise ValueError("a CSV holds the magnetometer on the accelerometer's rows: its "
                             "rate must divide the accelerometer's")
        m = np.full((len(session.t_acc), 3), np.nan)
        m[rows] = stream.values
        columns.append(m)
        names += ["mx", "my", "mz"]
    if triads:
        for stream in session.others:
            if stream.kind in ("acc", "gyro"):
                if not np.array_equal(stream.t, session.t_acc):
                    raise ValueError(f"a CSV holds {stream.name} on the accelerometer's rows: "
                                     "it needs the same timestamps")
                columns.append(stream.values)
                names += [f"{stream.instance}{a}" for a in "xyz"]
            elif stream.kind == "temp":
                columns.append(np.interp(session.t_acc, stream.t, stream.values[:, 0])[:, None])
                names.append("temp")
    head = ""
    if preamble is None:
        columns.insert(0, session.t_acc[:, None])
        names.insert(0, "t")
    else:
        head = "".join(f"{key},{value:g}\n" for key, value in preamble.items())
    buf = io.StringIO()
    np.savetxt(buf, np.hstack(columns), fmt="%.17g", delimiter=",")
    text = head + ",".join(names) + "\n" + buf.getvalue().replace("nan", "")
    if cut_last_line:
        last = text.rindex("\n", 0, len(text) - 1) + 1
        text = text[: last + (len(text) - last) // 2]  # half a row, no newline after it
    write_text_atomic(path, text)


def write_truth(path: str | os.PathLike, truth: Truth) -> None:
    write_text_atomic(path, json.dumps(truth.to_dict(), indent=2) + "\n")


def write_calibrated(path: str | os.PathLike, cal: CalibratedSignals) -> None:
    """Calibrated signals in the format named by the file's ending.

    Tables hold one row per accelerometer sample (``t, ax, ay, az``) and, when the gyroscope
    runs at the same timestamps, ``gx, gy, gz`` beside them; otherwise the gyroscope goes in
    a second table (``NAME.gyro.EXT``) for CSV/Parquet, or in ``gyro``/``t_gyro`` in .mat.
    A calibrated magnetometer: ``mag``/``t_mag`` in .mat; in a table ``mx, my, mz`` on the
    accelerometer's rows of its timestamps, empty on the others (a table's magnetometer is
    read so), and left out of a table when its clock is its own (:func:`mag_rows`).
    """
    fmt = output_format(path)
    if fmt == "mat":
        from scipy.io import savemat

        data = {"acc": cal.acc, "t_acc": cal.t_acc}
        if cal.gyro is not None:
            data |= {"gyro": cal.gyro, "t_gyro": cal.t_gyro}
        if cal.mag is not None:
            data |= {"mag": cal.mag, "t_mag": cal.t_mag}
        data |= extra_variables(cal.columns)

        def _w(tmp: Path) -> None:
            with open(tmp, "wb") as f:
                savemat(f, data, do_compression=True, oned_as="column")

        write_atomic(path, _w)
        return
    import polars as pl

    cols = {"t": cal.t_acc, "ax": cal.acc[:, 0], "ay": cal.acc[:, 1], "az": cal.acc[:, 2]}
    shared = cal.gyro is not None and np.array_equal(cal.t_acc, cal.t_gyro)
    if shared:
        cols |= {"gx": cal.gyro[:, 0], "gy": cal.gyro[:, 1], "gz": cal.gyro[:, 2]}
    rows = mag_rows(cal)
    if rows is not None:
        m = np.full((len(cal.t_acc), 3), np.nan)
        m[rows] = cal.mag
        cols |= {"mx": m[:, 0], "my": m[:, 1], "mz": m[:, 2]}
    cols |= cal.columns
    df = pl.DataFrame(cols)
    if rows is not None:
        df = df.with_columns(pl.col("mx", "my", "mz").fill_nan(None))  # empty cells
    if cal.columns:  # a triad without a sample at a row: an empty cell
        df = df.with_columns(pl.col(*cal.columns).fill_nan(None))
    _write_table(path, df, fmt)
    if cal.gyro is not None and not shared:
        p = Path(path)
        gpath = p.with_name(p.stem + ".gyro" + p.suffix)
        _write_table(gpath, pl.DataFrame({"t": cal.t_gyro, "gx": cal.gyro[:, 0],
                                          "gy": cal.gyro[:, 1], "gz": cal.gyro[:, 2]}), fmt)


def extra_variables(columns: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """A .mat file's variables for the columns beside the pair, on ``t_acc``: each triad's
    x, y, z as one (N, 3) variable named by its prefix (``a2``, ``g2``, ``ac``), a single
    column as itself (``temp``)."""
    out: dict[str, np.ndarray] = {}
    names = list(columns)
    for name in names:
        if name[-1:] in "xyz" and all(name[:-1] + a in columns for a in "xyz"):
            if name[-1] == "x":
                out[name[:-1]] = np.column_stack([columns[name[:-1] + a] for a in "xyz"])
        else:
            out[name] = np.asarray(columns[name])[:, None]
    return out


def mag_rows(cal: CalibratedSignals):
    """The accelerometer's rows of the calibrated magnetometer's timestamps, when every one is
    an accelerometer timestamp (a table's magnetometer); None without one or on its own
    clock."""
    if cal.mag is None or len(cal.t_mag) == 0:
        return None
    rows = np.minimum(np.searchsorted(cal.t_acc, cal.t_mag), len(cal.t_acc) - 1)
    return rows if np.array_equal(cal.t_acc[rows], cal.t_mag) else None


def _write_table(path: str | os.PathLike, df, fmt: str) -> None:
    def _w(tmp: Path) -> None:
        if fmt == "parquet":
            df.write_parquet(tmp)
        else:
            df.write_csv(tmp)

    write_atomic(path, _w)
