"""MATLAB v5 numeric variables read straight into their final arrays (method.md §0: the front).

scipy's reader wants the whole file in memory, the structural check
(:mod:`imucal.io.mat5_check`) needs a second, inflated copy of it, and the arrays scipy makes
are a third; a 6-hour 1 kHz session then peaks at three times its own size while loading. This
reads a file element by element from disk: the few bytes of each variable's tag, flags,
dimensions and name, then its data, inflated (when compressed) a piece at a time and written
from each piece into the one array that is kept, laid out as the loader will use it (samples
along rows, C order), so that nothing signal-sized is copied on the way to the
:class:`~imucal.session.Session`. The variables are independent streams: their data are
inflated in parallel threads (zlib and the copies release the GIL), as many as the caller allows
(:mod:`imucal.io.load_mat5_pool`); the result is the same to the bit in any number of threads.

It reads what a recording holds: real, non-sparse numeric matrices. Every other variable
(text, complex, sparse, struct, cell) is checked as before and skipped, as
:func:`imucal.io.readers._as_matrix` skips it after scipy. Anything it does not follow -- an
inconsistent length, an unusual type -- is :class:`Unsupported`: the caller then reads the file
the old way, whose messages name what is wrong, so no file is refused or read differently than
before, only read with less memory. A variable whose data do not inflate, or end early, is
:class:`CorruptVariable`, named: the old way refuses such a file too (its check inflates every
variable), but cannot name the variable.
"""

from __future__ import annotations

import os
import struct
import zlib
from collections.abc import Callable, Iterator
from pathlib import Path

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
_CHUNK = 1 << 20  # bytes of an uncompressed variable read at a time
_READ = 1 << 16  # compressed bytes read at a time
# Inflated bytes asked of zlib at a time: CPython returns up to 32 KiB in one buffer, more in
# blocks it then joins (a copy of every byte); a 64 KiB input keeps zlib's unconsumed tail (a
# copy too) small. Measured on a 60-minute session: 0.41 s against 0.61 s for 1 MiB pieces.
_PIECE = 1 << 15
_HEAD = 1 << 12  # bytes of a matrix element that hold its flags, dimensions and name


class Unsupported(Exception):
    """Not a file this reader follows; read it the general way."""


class CorruptVariable(Exception):
    """A variable's data do not inflate or end early: ``name`` and ``what`` say which, how."""

    def __init__(self, name: str, what: str) -> None:
        super().__init__(f"variable {name!r} {what}")
        self.name, self.what = name, what


class _Stopped(Exception):
    """An earlier variable failed: this one's work would be thrown away."""


Job = Callable[[Callable[[], bool]], None]  # fills one variable's array; its argument: stop?


def read_mat5_arrays(path: Path, spill: Spill | None = None, threads: int = 1,
                     skipped: dict[str, str] | None = None) -> dict[str, np.ndarray]:
    """Every real numeric 2-D variable of a MATLAB v5 file, as float64, by name; ``spill``
    allocates them (large ones mapped from a temporary file, :mod:`imucal.io.spill`); their
    data are inflated in up to ``threads`` threads.

    A matrix with at least as many rows as columns is C-ordered, one with more columns than
    rows (3 x N) Fortran-ordered: either way its samples are rows of a C-ordered array once
    oriented (:mod:`imucal.io.mat_layout`). Raises :class:`Unsupported` where the general
    reader must decide, :class:`CorruptVariable` for a variable that does not inflate.
    ``skipped`` receives the other variables' names and what each is, in words ("complex
    numbers", "a sparse matrix"), for a message that names them.
    """
    from imucal.io.load_mat5_pool import run_in_order

    spill = spill if spill is not None else Spill(IN_MEMORY)
    fd = os.open(path, os.O_RDONLY)
    try:
        found: dict[str, np.ndarray] = {}
        run_in_order(_jobs(fd, found, spill, {} if skipped is None else skipped), threads)
        return found
    finally:
        os.close(fd)


def _jobs(fd: int, found: dict[str, np.ndarray], spill: Spill, skipped: dict[str, str]
          ) -> Iterator[tuple[Job, Callable[[], None]]]:
    """Each variable's job (reading its data) and what keeps its array once the job is done,
    in the order of the file; the heads are read here, in the calling thread, so that ``spill``
    is only ever used from one thread."""
    head = os.pread(fd, 128, 0)
    end = os.fstat(fd).st_size
    if len(head) < 128 or head[126:128] not in (b"IM", b"MI"):
        raise Unsupported("header")
    fmt = "<" if head[126:128] == b"IM" else ">"
    pos = 128
    while end - pos >= 8:
        kind, nbytes = struct.unpack(fmt + "II", os.pread(fd, 8, pos))
        body = pos + 8
        if kind == _COMPRESSED and nbytes > end - body:
            _truncated(fd, body, end - body, fmt, head)  # the old way refuses it: name it
        if kind >> 16 or nbytes > end - body or kind not in (_MATRIX, _COMPRESSED):
            raise Unsupported("top-level element")
        if kind == _COMPRESSED:
            stream: _Stream = _Inflating(fd, body, nbytes)
            inner_kind, inner_n = struct.unpack(fmt + "II", stream.read(8))
            if inner_kind != _MATRIX:
                raise Unsupported("compressed element")
            yield _variable(stream, inner_n, fmt, found, head, spill, compressed=True,
                            skipped=skipped)
            pos = body + nbytes
        else:
            yield _variable(_Plain(fd, body, nbytes), nbytes, fmt, found, head, spill,
                            compressed=False, skipped=skipped)
            pos = body + nbytes + (-nbytes) % 8


def _truncated(fd: int, body: int, available: int, fmt: str, header: bytes) -> None:
    """A compressed variable the file ends inside: CorruptVariable when its name can be read."""
    stream = _Inflating(fd, body, available)
    try:
        inner_kind, _ = struct.unpack(fmt + "II", stream.read(8))
        fields = _fields(stream.read(_HEAD), fmt) if inner_kind == _MATRIX else None
    except (struct.error, Unsupported, CorruptVariable):
        return
    if fields is not None:
        raise CorruptVariable(fields[0], "is cut short: the file ends inside it")


class _Stream:
    """The bytes of one element's body, read in order."""

    def read(self, n: int) -> bytes:
        """Up to ``n`` bytes (fewer only at the end)."""
        raise NotImplementedError

    def pieces(self, n: int, stop: Callable[[], bool]) -> Iterator[bytes | memoryview]:
        """Exactly the next ``n`` bytes, in pieces; :class:`Unsupported` if there are fewer."""
        while n > 0:
            if stop():
                raise _Stopped
            got = self.read(min(n, _CHUNK))
            if not got:
                raise Unsupported("element shorter than its data")
            n -= len(got)
            yield got


class _Plain(_Stream):
    def __init__(self, fd: int, pos: int, nbytes: int) -> None:
        self.fd, self.pos, self.left = fd, pos, nbytes

    def read(self, n: int) -> bytes:
        data = os.pread(self.fd, min(n, self.left), self.pos)  # no shared file position
        self.pos += len(data)
        self.left -= len(data)
        return data


class _Inflating(_Stream):
    def __init__(self, fd: int, pos: int, nbytes: int) -> None:
        self.fd, self.pos, self.left = fd, pos, nbytes
        self.z = zlib.decompressobj()
        self.tail = b""  # input zlib has not consumed yet
        self.name = ""  # the variable's, once known: it names a stream that does not inflate

    def _piece(self, n: int) -> bytes:
        """At most ``min(n, _PIECE)`` inflated bytes; empty at the end of the stream."""
        while not self.z.eof:
            if not self.tail:
                if not self.left:
                    return b""
                self.tail = os.pread(self.fd, min(_READ, self.left), self.pos)
                if not self.tail:
                    return b""
                self.pos += len(self.tail)
                self.left -= len(self.tail)
            try:
                got = self.z.decompress(self.tail, min(n, _PIECE))
            except zlib.error as e:
                if self.name:
                    raise CorruptVariable(self.name, f"does not inflate ({e})") from None
                raise Unsupported("does not inflate") from None
            self.tail = self.z.unconsumed_tail
            if got:
                return got
        return b""

    def read(self, n: int) -> bytes:
        pieces: list[bytes] = []
        while n > 0 and (got := self._piece(n)):
            pieces.append(got)
            n -= len(got)
        return b"".join(pieces)

    def pieces(self, n: int, stop: Callable[[], bool]) -> Iterator[bytes]:
        while n > 0:
            if stop():
                raise _Stopped
            got = self._piece(n)
            if not got:
                raise CorruptVariable(self.name, "ends before its data: the file is cut short "
                                      "or corrupt")
            n -= len(got)
            yield got


def _skip(stream: _Stream, n: int) -> None:
    while n > 0:
        got = len(stream.read(min(n, _CHUNK)))
        if not got:
            return
        n -= got


def _variable(stream: _Stream, nbytes: int, fmt: str, found: dict[str, np.ndarray],
              header: bytes, spill: Spill, compressed: bool, skipped: dict[str, str]
              ) -> tuple[Job, Callable[[], None]]:
    """One miMATRIX element's head, read now; returns the job that reads its data (when a real
    numeric 2-D matrix; else the element is checked and skipped now) and what keeps it."""
    def nothing(stop: Callable[[], bool]) -> None:
        if compressed:
            _end_of_stream(stream, nbytes - used)

    if nbytes == 0:
        used = 0
        return nothing, lambda: None  # an empty matrix
    head = stream.read(min(nbytes, _HEAD))
    fields = _fields(head, fmt)
    if fields is None:  # not numeric: check it whole (as the general reader would) and skip
        rest = stream.read(nbytes - len(head)) if nbytes > len(head) else b""
        element = struct.pack(fmt + "II", _MATRIX, nbytes) + head + rest
        try:
            check_mat5(header + element + bytes((-nbytes) % 8))
        except CorruptMat:
            raise Unsupported("a corrupt variable") from None
        used = len(head) + len(rest)
        what = _skipped_as(head, fmt)
        return nothing, (lambda: None) if what is None else (
            lambda: skipped.__setitem__(*what))
    name, (rows, cols), dtype, data_at, data_n = fields
    if data_n != rows * cols * np.dtype(dtype).itemsize or data_at + data_n > nbytes:
        raise Unsupported("data size")
    if isinstance(stream, _Inflating):
        stream.name = name
    if rows * cols == 0:
        used = len(head)
        return nothing, lambda: found.pop(name, None)  # empty: skipped like scipy's
    used = max(len(head), data_at + data_n)
    out = _allocate(rows, cols, spill)
    pending = head[data_at:data_at + data_n]
    data = _Prefixed(pending, stream) if pending else stream
    order = np.dtype(dtype).newbyteorder(fmt)

    def job(stop: Callable[[], bool]) -> None:
        _read_data(data, out, order, stop)
        nothing(stop)

    return job, lambda: found.__setitem__(name, out)


def _end_of_stream(stream: _Stream, left: int) -> None:
    """Read a compressed element to its end (zlib checks its checksum there): one variable."""
    _skip(stream, left)
    if len(stream.read(_CHUNK)) >= 8:  # several elements in one stream: rare
        raise Unsupported("compressed stream of several elements")


class _Prefixed(_Stream):
    """Bytes already read, then the rest of the stream."""

    def __init__(self, first: bytes, rest: _Stream) -> None:
        self.first, self.rest = first, rest

    def read(self, n: int) -> bytes:
        if self.first:
            out, self.first = self.first[:n], self.first[n:]
            return out
        return self.rest.read(n)

    def pieces(self, n: int, stop: Callable[[], bool]) -> Iterator[bytes | memoryview]:
        if self.first:
            out, self.first = self.first[:n], self.first[n:]
            n -= len(out)
            yield out
        if n:
            yield from self.rest.pieces(n, stop)


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


_SKIPPED_CLASSES = {1: "a cell array", 2: "a struct", 3: "an object", 4: "text (char)",
                    5: "a sparse matrix"}


def _skipped_as(head: bytes, fmt: str) -> tuple[str, str] | None:
    """A skipped variable's name and what it is in words; None where the head says neither."""
    u32 = fmt + "II"
    try:
        flags = struct.unpack(fmt + "I", head[8:12])[0]
        cls = flags & 0xFF
        what = _SKIPPED_CLASSES.get(cls) or (
            "complex numbers" if flags & _COMPLEX else f"MATLAB class {cls}")
        _, n = struct.unpack(u32, head[16:24])  # dimensions: any number of them
        at = 24 + n + (-n) % 8
        kind, n = struct.unpack(u32, head[at:at + 8])
        name = head[at + 4:at + 4 + (kind >> 16)] if kind >> 16 else head[at + 8:at + 8 + n]
    except struct.error:
        return None
    return (name.decode("latin-1"), what) if name else None


def _allocate(rows: int, cols: int, spill: Spill) -> np.ndarray:
    """The float64 (rows, cols) array a variable is read into: Fortran order when there are
    more columns than rows (its column-major data then fill it in order), else C order."""
    if cols > rows or cols == 1 or rows == 1:
        return spill.empty((rows, cols), order="F")
    return spill.empty((rows, cols))


def _read_data(stream: _Stream, out: np.ndarray, dtype: np.dtype, stop: Callable[[], bool]
               ) -> None:
    """Column-major data into ``out``: in order when Fortran-ordered, else a column at a time."""
    if out.flags.f_contiguous:
        _fill(stream.pieces(out.size * dtype.itemsize, stop), out.reshape(-1, order="F"), dtype)
        return
    for j in range(out.shape[1]):
        _fill(stream.pieces(out.shape[0] * dtype.itemsize, stop), out[:, j], dtype)


def _fill(pieces: Iterator[bytes | memoryview], target: np.ndarray, dtype: np.dtype) -> None:
    """``target[:] =`` the values of ``dtype`` the pieces hold, written (and converted) from
    each piece as it comes: no buffer between. A value split across two pieces is joined."""
    size, at, carry = dtype.itemsize, 0, b""
    for piece in pieces:
        start = 0
        if carry:
            start = size - len(carry)
            carry += bytes(piece[:start])
            if len(carry) < size:
                continue
            target[at] = np.frombuffer(carry, dtype)[0]
            at, carry = at + 1, b""
        whole = (len(piece) - start) // size
        if whole:
            target[at:at + whole] = np.frombuffer(piece, dtype, whole, start)
            at += whole
        carry = bytes(piece[start + whole * size:])
