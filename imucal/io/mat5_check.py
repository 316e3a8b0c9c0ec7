"""A structural check of MATLAB v5 files before scipy reads them.

scipy's MAT-file reader trusts the file: a corrupt data-type code or an element size that
runs past its parent crashes the whole process (a segmentation fault, found by the fuzz test),
which no ``try`` can catch. This walks the tags (MAT-File Format, MathWorks, section 1) and
refuses anything inconsistent, so only well-formed files reach scipy.
"""

from __future__ import annotations

import io
import struct
import zlib

# miINT8 … miUTF32 (8, 10, 11 are reserved)
_ITEMSIZE = {1: 1, 2: 1, 3: 2, 4: 2, 5: 4, 6: 4, 7: 4, 9: 8, 12: 8, 13: 8, 16: 1, 17: 2, 18: 4}
_MATRIX, _COMPRESSED = 14, 15
_MAX_DEPTH = 16
_MAX_INFLATE = 4 << 30


class CorruptMat(ValueError):
    """The file's structure is inconsistent; the message says where."""


def check_mat5(data: bytes, sink: io.BufferedIOBase | io.BytesIO | None = None) -> None:
    """Raise :class:`CorruptMat` unless every element of a v5 MAT file is well formed.

    The check has to inflate every compressed variable; with a ``sink`` it also writes the
    same file with those variables stored inflated, so that the reader does not inflate them
    a second time (half the load time of a large compressed session). Of an inflated stream
    only its first element is kept, the one variable a reader takes from it.
    """
    if len(data) < 128:
        raise CorruptMat("shorter than the 128-byte MAT-file header")
    endian = data[126:128]
    if endian not in (b"IM", b"MI"):
        raise CorruptMat("bad byte-order mark in the header")
    fmt = "<II" if endian == b"IM" else ">II"
    if sink is not None:
        sink.write(data[:128])
    _walk(data, 128, len(data), fmt, depth=0, top=True, sink=sink)


def _write_first_element(sink: io.BufferedIOBase | io.BytesIO, inner: bytes, fmt: str) -> None:
    """Write the first element of an inflated stream (already checked), padded to 8 bytes."""
    kind, nbytes = struct.unpack(fmt, inner[:8])
    size = 8 if kind >> 16 else 8 + nbytes
    sink.write(memoryview(inner)[:size])  # a view: the stream can be hundreds of MB
    sink.write(bytes((-size) % 8))


def _walk(b: bytes, pos: int, end: int, fmt: str, depth: int, top: bool,
          sink: io.BufferedIOBase | io.BytesIO | None = None) -> None:
    if depth > _MAX_DEPTH:
        raise CorruptMat("elements nested too deeply")
    while pos < end:
        start = pos
        if end - pos < 8:
            if top:
                return  # trailing padding after the last element
            raise CorruptMat(f"truncated element tag at byte {pos}")
        kind, nbytes = struct.unpack(fmt, b[pos:pos + 8])
        if kind >> 16:  # small data element: type and size packed in 4 bytes
            small_kind, small_n = kind & 0xFFFF, kind >> 16
            if small_kind not in _ITEMSIZE or small_n > 4:
                raise CorruptMat(f"bad small data element at byte {pos}")
            pos += 8
            if sink is not None:
                sink.write(b[start:pos])
            continue
        body = pos + 8
        if nbytes > end - body:
            raise CorruptMat(f"element at byte {pos} runs past the end of its container")
        inner = None
        if kind == _COMPRESSED:
            if not top:
                raise CorruptMat(f"compressed element inside a matrix at byte {pos}")
            try:
                inner = zlib.decompressobj().decompress(memoryview(b)[body:body + nbytes],
                                                        _MAX_INFLATE)
            except zlib.error as e:
                raise CorruptMat(f"compressed element at byte {pos} does not inflate ({e})") \
                    from None
            _walk(inner, 0, len(inner), fmt, depth + 1, top=True)
        elif kind == _MATRIX:
            _matrix(b, body, body + nbytes, fmt, depth + 1)
        elif kind in _ITEMSIZE:
            if nbytes % _ITEMSIZE[kind]:
                raise CorruptMat(f"element at byte {pos} is not a whole number of items")
        else:
            raise CorruptMat(f"unknown data type {kind} at byte {pos}")
        pos = body + nbytes
        if not top or kind != _COMPRESSED:
            pos += (-nbytes) % 8  # elements are padded to 8 bytes
        if pos > end and not top:
            raise CorruptMat(f"padding past the end of a matrix at byte {pos}")
        if sink is not None:
            if inner is None:
                sink.write(memoryview(b)[start:min(pos, end)])
            elif len(inner) >= 8:
                _write_first_element(sink, inner, fmt)


def _matrix(b: bytes, pos: int, end: int, fmt: str, depth: int) -> None:
    """A miMATRIX: flags, dimensions, name, then its data (checked element by element)."""
    if end == pos:
        return  # an empty matrix
    if end - pos < 16:
        raise CorruptMat(f"matrix at byte {pos} too short for its flags")
    _walk(b, pos, end, fmt, depth, top=False)
