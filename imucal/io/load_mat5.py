"""MATLAB v5 numeric variables read straight into their final arrays (method.md §0: the front).

scipy's reader wants the whole file in memory, the structural check
(:mod:`imucal.io.mat5_check`) needs a second, inflated copy of it, and the arrays scipy makes
are a third; a 6-hour 1 kHz session then peaks at three times its own size while loading. This
reads a file element by element from disk: the few bytes of each variable's tag, flags,
dimensions and name, then its data, inflated (when compressed) and converted in bounded chunks
into the one array that is kept, laid out as the loader will use it (samples along rows, C
order), so that nothing signal-sized is copied on the way to the
:class:`~imucal.session.Session`.

It reads what a recording holds: real, non-sparse numeric matrices. Every other variable
(text, complex, sparse, struct, cell) is checked as before and skipped, as
:func:`imucal.io.readers._as_matrix` skips it after scipy. Anything it does not follow -- an
inconsistent length, a compressed stream that does not inflate, an unusual type -- is
:class:`Unsupported`: the caller then reads the file the old way, whose messages name what is
wrong, so no file is refused or read differently than before, only read with less memory.
"""

from __future__ import annotations

import io
import struct
import zlib
from pathlib import Path
from typing import BinaryIO

import numpy as np

from imucal.io.mat5_check import CorruptMat, check_mat5
from imucal.io.spill import IN_MEMORY, Spill

_MATRIX, _COMPRESSED = 14, 15
# miINT8 ... miUINT64 data types and mxINT8 ... mxUINT64 / mxSINGLE / mxDOUBLE array classes
_TYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 9: "f8", 12: "i8",
          13: "u8"}
_CLASSES = {6: "f8", 7: "f4", 8: "i1", 9: "u1", 10: "i2", 11: "u2", 12: "i4", 13: "u4",
            14: "i8", 15: "u8"}
_COMPLEX = 0x0800
_CHUNK = 1 << 20  # elements converted at a time: 8 MB of float64
_READ = 1 << 20  # bytes read (and inflated) at a time
_HEAD = 1 << 12  # bytes of a matrix element that hold its flags, dimensions and name


class Unsupported(Exception):
    """Not a file this reader follows; read it the general way."""


def read_mat5_arrays(path: Path, spill: Spill | None = None) -> dict[str, np.ndarray]:
    """Every real numeric 2-D variable of a MATLAB v5 file, as float64, by name; ``spill``
    allocates them (large ones mapped from a temporary file, :mod:`imucal.io.spill`).

    A matrix with at least as many rows as columns is C-ordered, one with more columns than
    rows (3 x N) Fortran-ordered: either way its samples are rows of a C-ordered array once
    oriented (:mod:`imucal.io.mat_layout`). Raises :class:`Unsupported` where the general
    reader must decide.
    """
    found: dict[str, np.ndarray] = {}
    spill = spill if spill is not None else Spill(IN_MEMORY)
    with path.open("rb") as fh:
        head = fh.read(128)
        end = fh.seek(0, io.SEEK_END)
        if len(head) < 128 or head[126:128] not in (b"IM", b"MI"):
            raise Unsupported("header")
        fmt = "<" if head[126:128] == b"IM" else ">"
        pos = 128
        while end - pos >= 8:
            fh.seek(pos)
            kind, nbytes = struct.unpack(fmt + "II", fh.read(8))
            if kind >> 16 or nbytes > end - pos - 8 or kind not in (_MATRIX, _COMPRESSED):
                raise Unsupported("top-level element")
            body = pos + 8
            if kind == _COMPRESSED:
                stream: _Stream = _Inflating(fh, body, nbytes)
                inner_kind, inner_n = struct.unpack(fmt + "II", stream.read(8))
                if inner_kind != _MATRIX:
                    raise Unsupported("compressed element")
                used = _variable(stream, inner_n, fmt, found, head, spill)
                _skip(stream, inner_n - used)
                if len(stream.read(_READ)) >= 8:  # several elements in one stream: rare
                    raise Unsupported("compressed stream of several elements")
                pos = body + nbytes
            else:
                _variable(_Plain(fh, body, nbytes), nbytes, fmt, found, head, spill)
                pos = body + nbytes + (-nbytes) % 8
    return found


class _Stream:
    """The bytes of one element's body, read in order."""

    def read(self, n: int) -> bytes:
        raise NotImplementedError

    def read_into(self, view: memoryview) -> None:
        """Fill ``view`` exactly."""
        at = 0
        while at < len(view):
            got = self.read(min(len(view) - at, _READ))
            if not got:
                raise Unsupported("element shorter than its data")
            view[at:at + len(got)] = got
            at += len(got)


class _Plain(_Stream):
    def __init__(self, fh: BinaryIO, pos: int, nbytes: int) -> None:
        self.fh, self.pos, self.left = fh, pos, nbytes

    def read(self, n: int) -> bytes:
        self.fh.seek(self.pos)
        data = self.fh.read(min(n, self.left))
        self.pos += len(data)
        self.left -= len(data)
        return data

    def read_into(self, view: memoryview) -> None:
        if len(view) > self.left:
            raise Unsupported("element shorter than its data")
        self.fh.seek(self.pos)
        if self.fh.readinto(view) != len(view):  # straight from the file into the array
            raise Unsupported("file shorter than its element")
        self.pos += len(view)
        self.left -= len(view)


class _Inflating(_Stream):
    def __init__(self, fh: BinaryIO, pos: int, nbytes: int) -> None:
        self.fh, self.pos, self.left = fh, pos, nbytes
        self.z = zlib.decompressobj()
        self.tail = b""  # input zlib has not consumed yet

    def read(self, n: int) -> bytes:
        pieces: list[bytes] = []
        got = 0
        try:
            while got < n and not self.z.eof:
                if not self.tail:
                    if not self.left:
                        break
                    self.fh.seek(self.pos)
                    self.tail = self.fh.read(min(_READ, self.left))
                    self.pos += len(self.tail)
                    self.left -= len(self.tail)
                pieces.append(self.z.decompress(self.tail, n - got))
                got += len(pieces[-1])
                self.tail = self.z.unconsumed_tail
        except zlib.error:
            raise Unsupported("does not inflate") from None
        return pieces[0] if len(pieces) == 1 else b"".join(pieces)


def _skip(stream: _Stream, n: int) -> None:
    while n > 0:
        got = len(stream.read(min(n, _READ)))
        if not got:
            return
        n -= got


def _variable(stream: _Stream, nbytes: int, fmt: str, found: dict[str, np.ndarray],
              header: bytes, spill: Spill) -> int:
    """One miMATRIX element: kept when a real numeric 2-D matrix, else checked and skipped.
    Returns how many bytes of its body were read."""
    if nbytes == 0:
        return 0  # an empty matrix
    head = stream.read(min(nbytes, _HEAD))
    fields = _fields(head, fmt)
    if fields is None:  # not numeric: check it whole (as the general reader would) and skip
        rest = stream.read(nbytes - len(head)) if nbytes > len(head) else b""
        element = struct.pack(fmt + "II", _MATRIX, nbytes) + head + rest
        try:
            check_mat5(header + element + bytes((-nbytes) % 8))
        except CorruptMat:
            raise Unsupported("a corrupt variable") from None
        return len(head) + len(rest)
    name, dims, dtype, data_at, data_n = fields
    rows, cols = dims
    if data_n != rows * cols * np.dtype(dtype).itemsize or data_at + data_n > nbytes:
        raise Unsupported("data size")
    if rows * cols == 0:
        found.pop(name, None)  # empty: skipped like scipy's empty arrays
        return len(head)
    pending = head[data_at:data_at + data_n]
    data = _Prefixed(pending, stream) if pending else stream
    found[name] = _read_data(data, rows, cols, np.dtype(dtype).newbyteorder(fmt), spill)
    return max(len(head), data_at + data_n)


class _Prefixed(_Stream):
    """Bytes already read, then the rest of the stream."""

    def __init__(self, first: bytes, rest: _Stream) -> None:
        self.first, self.rest = first, rest

    def read(self, n: int) -> bytes:
        if self.first:
            out, self.first = self.first[:n], self.first[n:]
            return out
        return self.rest.read(n)


def _fields(head: bytes, fmt: str) -> tuple[str, tuple[int, int], str, int, int] | None:
    """Name, dimensions, stored data type, and where and how long the data is, of a real
    numeric matrix; None for any other variable."""
    u32 = fmt + "II"
    try:
        kind, n = struct.unpack(u32, head[0:8])
        if kind != 6 or n != 8:  # array flags: miUINT32, 8 bytes
            raise Unsupported("array flags")
        flags = struct.unpack(fmt + "I", head[8:12])[0]
        cls = flags & 0xFF
        if cls not in _CLASSES or flags & _COMPLEX:  # logicals: scipy reads them as uint8
            return None
        kind, n = struct.unpack(u32, head[16:24])
        if kind != 5 or n != 8:  # dimensions: 2 x miINT32 (more dimensions: general path)
            raise Unsupported("dimensions")
        rows, cols = struct.unpack(fmt + "ii", head[24:32])
        at = 32
        kind, n = struct.unpack(u32, head[at:at + 8])
        if kind >> 16:  # the name as a small element: 4 bytes of tag, at most 4 of name
            name, kind = head[at + 4:at + 4 + (kind >> 16)], kind & 0xFFFF
            at += 8
        else:
            name = head[at + 8:at + 8 + n]
            if len(name) != n:
                raise Unsupported("name")
            at += 8 + n + (-n) % 8
        if kind != 1:  # miINT8
            raise Unsupported("name")
        kind, n = struct.unpack(u32, head[at:at + 8])
        if kind >> 16:  # a small data element: its at most 4 bytes inside the tag
            kind, n, at = kind & 0xFFFF, kind >> 16, at - 4
    except struct.error:
        raise Unsupported("matrix header") from None
    if kind not in _TYPES or rows < 0 or cols < 0:
        raise Unsupported("data element")
    stored, klass = _TYPES[kind], _CLASSES[cls]
    if stored != klass and klass != "f8":  # scipy casts to the class; double is exact
        raise Unsupported("data type and class differ")
    return name.decode("latin-1"), (rows, cols), stored, at + 8, n


def _read_data(stream: _Stream, rows: int, cols: int, dtype: np.dtype, spill: Spill
               ) -> np.ndarray:
    """Column-major data into a float64 (rows, cols) array: Fortran order when there are more
    columns than rows (read straight in), else C order (written a column at a time)."""
    if cols > rows or cols == 1 or rows == 1:
        out = spill.empty((rows, cols), order="F")
        flat = out.reshape(-1, order="F")  # a view: same memory
        if dtype == np.dtype("<f8") or dtype == np.dtype("=f8"):
            stream.read_into(memoryview(flat).cast("B"))
        else:
            _convert(stream, flat, dtype)
        return out
    out = spill.empty((rows, cols))
    for j in range(cols):
        _convert(stream, out[:, j], dtype)
    return out


def _convert(stream: _Stream, target: np.ndarray, dtype: np.dtype) -> None:
    """``target[:] = `` the next ``len(target)`` stored values, a bounded chunk at a time."""
    buf = np.empty(min(_CHUNK, len(target)), dtype=dtype)
    for lo in range(0, len(target), len(buf)):
        hi = min(lo + len(buf), len(target))
        part = buf[:hi - lo]
        stream.read_into(memoryview(part.view(np.uint8)))
        target[lo:hi] = part
