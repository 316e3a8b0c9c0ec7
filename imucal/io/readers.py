"""Recognise a file's format from its content and read it (method.md §0).

The format is never taken from the extension (the imu_tk example ``xsens_acc.mat`` is plain
text): MATLAB v5 ``.mat``, MATLAB v7.3 / HDF5, Parquet, and otherwise text
(:mod:`imucal.io.text_table`). Whatever a parsing library raises becomes one
:class:`~imucal.errors.ImucalError` line naming the file.
"""

from __future__ import annotations

import io
import sys
from pathlib import Path

import numpy as np

from imucal.errors import ImucalError
from imucal.io.file_contents import Table, Variables
from imucal.io.spill import Spill
from imucal.io.text_table import read_text, series_to_float


def display_name(path: Path) -> str:
    """How a file is named in messages."""
    return path.name or str(path)


_MAGIC_MAT5 = b"MATLAB 5.0 MAT-file"
_MAGIC_HDF5 = b"\x89HDF\r\n\x1a\n"
_MAGIC_PARQUET = b"PAR1"
# Formats people try that we do not read: name them instead of calling them garbled text.
_UNSUPPORTED_MAGIC = {
    b"PK\x03\x04": "a zip archive (or an Excel .xlsx workbook); export it as CSV",
    b"\x1f\x8b": "gzip-compressed; decompress it first",
    b"\x93NUMPY": "a NumPy .npy file; save it as CSV or .mat",
    b"\xff\xfe": "UTF-16 text; save it as UTF-8",
    b"\xfe\xff": "UTF-16 text; save it as UTF-8",
}


def read_file(path: Path, spill: Spill | None = None, threads: int = 1) -> Table | Variables:
    """Read any supported format; library exceptions become one-line ImucalErrors. ``spill``
    allocates the arrays of a MATLAB v5 file (large ones mapped, :mod:`imucal.io.spill`), whose
    variables are inflated in up to ``threads`` threads, and of a long text file (read a piece
    at a time from the spill's size up)."""
    source = display_name(path)
    try:
        with path.open("rb") as fh:
            head = fh.read(1024)
        if head.startswith(_MAGIC_MAT5):
            return _read_mat5(path, spill, threads)
        if head[:8] == _MAGIC_HDF5 or head[512:520] == _MAGIC_HDF5:
            return _read_hdf5(path)
        if head[:4] == _MAGIC_PARQUET:
            return _read_parquet(path)
        for magic, what in _UNSUPPORTED_MAGIC.items():
            if head.startswith(magic):
                raise ImucalError(f"unsupported format: {what}", source=source)
        if b"\x00" in head:
            raise ImucalError("unknown binary format; expected CSV/TSV/text, MATLAB .mat (v5 or "
                              "v7.3/HDF5) or Parquet", source=source)
        if _long_text(path, spill):
            from imucal.io.text_pieces import read_text_pieces

            assert spill is not None
            return read_text_pieces(path, source, spill)
        return read_text(path.read_bytes(), source)
    except ImucalError:
        raise
    except MemoryError:
        raise ImucalError("not enough memory to load the file", source=source) from None
    except OSError as exc:  # permission, an I/O error: the operating system's reason
        if exc.strerror is None:
            raise ImucalError(f"cannot read the file: {_one_line(exc)}", source=source) from None
        raise ImucalError(f"cannot be read ({exc.strerror})", source=source) from None
    except _parser_errors() as exc:  # any parser failure is a problem with the file, in one line
        raise ImucalError(f"cannot read the file: {_one_line(exc)}", source=source) from None


def _long_text(path: Path, spill: Spill | None) -> bool:
    """A text file read a piece at a time into the spill (:mod:`imucal.io.text_pieces`): from
    the size at which the spill maps an array (its policy's ``above_bytes``, the file's bytes
    here: a number in text takes more bytes than its float64), so a long CSV is held as a long
    .mat is."""
    above = spill.policy.above_bytes if spill is not None else None
    return above is not None and path.stat().st_size >= above


def _parser_errors() -> tuple[type[BaseException], ...]:
    """What a failing parser raises: polars reports some malformed input by panicking, and its
    PanicException is a BaseException. Looked up when an exception arrives (that is when an
    ``except`` clause is evaluated), as polars is imported only by the readers that need it."""
    exceptions = sys.modules.get("polars.exceptions")
    return (Exception,) if exceptions is None else (Exception, exceptions.PanicException)


def one_line_error(exc: BaseException) -> str:
    """A library's exception as a few words for a one-line message."""
    return _one_line(exc)


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    first = text[0] if text else ""
    return f"{type(exc).__name__}: {first[:200]}" if first else type(exc).__name__


def _as_matrix(value: object) -> np.ndarray | None:
    """A real numeric array as 2-D float64, or None for strings, structs, cells, logicals."""
    if not isinstance(value, np.ndarray) or value.dtype.kind not in "iuf" or value.size == 0:
        return None
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 1:
        arr = arr[:, None]
    if arr.ndim != 2:
        arr = np.squeeze(arr)
        if arr.ndim != 2:
            return None
    return arr


def _read_mat5(path: Path, spill: Spill | None, threads: int) -> Variables:
    """Numeric variables straight from the file into their arrays (:mod:`imucal.io.load_mat5`);
    a file that reader does not follow the general way: checked, then read by scipy."""
    from imucal.io.load_mat5 import CorruptVariable, Unsupported, read_mat5_arrays

    try:
        skipped: dict[str, str] = {}
        arrays = read_mat5_arrays(path, spill, threads, skipped)
        return Variables(path.name, arrays, skipped)
    except CorruptVariable as e:  # the general way refuses it too, without naming it
        raise ImucalError(f"corrupt MATLAB v5 file: the variable {e.what}",
                          source=display_name(path), field=e.name) from None
    except Unsupported:
        return _read_mat5_general(path)


def _read_mat5_general(path: Path) -> Variables:
    from scipy.io import loadmat

    from imucal.io.mat5_check import CorruptMat, check_mat5

    data = path.read_bytes()
    inflated = io.BytesIO()
    try:
        check_mat5(data, inflated)  # scipy crashes the process on some corrupt files
    except CorruptMat as e:
        raise ImucalError(f"corrupt MATLAB v5 file: {e}", source=display_name(path)) from None
    del data
    inflated.seek(0)
    raw = loadmat(inflated)  # the checked file, its variables already inflated by the check
    found, skipped = {}, {}
    for name, value in raw.items():
        if name.startswith("__"):
            continue
        matrix = _as_matrix(value)
        if matrix is not None:
            found[name] = matrix
        else:
            skipped[name] = _what_is(value)
    return Variables(path.name, found, skipped)


def _what_is(value: object) -> str:
    """A variable scipy read that is not a real numeric matrix, in words."""
    if not isinstance(value, np.ndarray):
        return "a sparse matrix" if hasattr(value, "tocsr") else type(value).__name__
    kind = value.dtype.kind
    if value.size == 0:
        return "empty"
    return {"c": "complex numbers", "U": "text (char)", "S": "text (char)", "b": "logical values",
            "O": "a cell array", "V": "a struct"}.get(kind, f"values of type {value.dtype}")


def _read_hdf5(path: Path) -> Variables:
    import h5py

    found, skipped = {}, {}
    with h5py.File(path, "r") as f:
        for name, item in f.items():
            if name.startswith("#"):
                continue
            cls = item.attrs.get("MATLAB_class")
            cls = cls.decode() if isinstance(cls, bytes) else cls
            if not isinstance(item, h5py.Dataset):  # MATLAB v7.3 keeps these as groups
                if "MATLAB_sparse" in item.attrs or cls == "struct":
                    skipped[name] = "a sparse matrix" if cls != "struct" else "a struct"
                continue
            if cls in ("char", "logical", "cell", "struct") or "MATLAB_empty" in item.attrs:
                skipped[name] = {"char": "text (char)", "logical": "logical values",
                                 "cell": "a cell array", "struct": "a struct"}.get(cls, "empty")
                continue
            names = item.dtype.names or ()
            if "real" in names and "imag" in names:  # how MATLAB v7.3 stores complex numbers
                skipped[name] = "complex numbers"
                continue
            matrix = _as_matrix(item[()])
            if matrix is None:
                continue
            # MATLAB writes column-major, so h5py sees every matrix transposed.
            found[name] = matrix.T if cls is not None else matrix
    return Variables(path.name, found, skipped)


def _read_parquet(path: Path) -> Table:
    import polars as pl

    frame = pl.read_parquet(path)
    seconds = set()
    cols = []
    for i, name in enumerate(frame.columns):
        s = frame.get_column(name)
        if s.dtype == pl.Datetime:
            s = s.dt.epoch("us").cast(pl.Float64) / 1e6
            seconds.add(i)
        elif s.dtype == pl.Duration:
            s = s.dt.total_microseconds().cast(pl.Float64) / 1e6
            seconds.add(i)
        cols.append(s)
    names = list(frame.columns)

    def column(i: int) -> np.ndarray:
        return series_to_float(cols[i], f"column {names[i]!r}", path.name, None)

    return Table(path.name, names, len(names), column, frozenset(seconds))
