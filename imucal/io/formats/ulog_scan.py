"""The compiled passes over a ULog file's bytes (numba), imported on a ULog's first read.

A ULog is a chain of messages, each ``uint16 size, uint8 type, payload[size]``: where one
message starts is known only once the one before it is read, so the walk is sequential. pyulog
walks it in Python (two ``file.read`` calls and a header parse per message, about 1 µs each,
every message of every topic decoded or not); here one compiled loop finds every message's
offset, and the payloads of the wanted topics are copied out in a second compiled loop, to be
viewed as numpy records with the topic's own layout.
"""

from __future__ import annotations

import numpy as np

from imucal.numerics.rk4.jit import jit

# How the walk ended.
CLEAN = 0  # the last message ends where the file ends
TRUNCATED = 1  # the file ends inside a message (a log cut short: power lost, copy cut)
IRREGULAR = 2  # a header no writer makes (type unknown, size 0): a corrupt stretch

# The message types of the ULog specification (docs.px4.io, "ULog File Format"): B F I M P Q
# (definitions), A R D L C S O (data section).
KNOWN_TYPES = np.zeros(256, dtype=np.bool_)
KNOWN_TYPES[[ord(c) for c in "BFIMPQARDLCSO"]] = True


@jit()
def _walk(buf, start, known, offsets):  # pragma: no cover - compiled
    """Walk the messages from ``start``: their count, where the walk stopped, and why
    (CLEAN, TRUNCATED, IRREGULAR). Offsets are written while ``offsets`` has room, so a first
    pass with an empty array counts and a second fills."""
    n = buf.size
    o = start
    k = 0
    while o + 3 <= n:
        size = np.int64(buf[o]) | (np.int64(buf[o + 1]) << 8)
        if size == 0 or not known[buf[o + 2]]:
            return k, o, 2
        if o + 3 + size > n:
            return k, o, 1
        if k < offsets.size:
            offsets[k] = o
        k += 1
        o += 3 + size
    return k, o, 0 if o == n else 1


def message_offsets(buf: np.ndarray, start: int) -> tuple[np.ndarray, int, int]:
    """Every message's offset from ``start``, where the walk stopped and why (see CLEAN,
    TRUNCATED, IRREGULAR)."""
    count, _, _ = _walk(buf, start, KNOWN_TYPES, np.empty(0, dtype=np.int64))
    offsets = np.empty(count, dtype=np.int64)
    count, stop, status = _walk(buf, start, KNOWN_TYPES, offsets)
    return offsets, int(stop), int(status)


@jit()
def _gather(buf, starts, width, out):  # pragma: no cover - compiled
    for i in range(starts.size):
        s = starts[i]
        for j in range(width):
            out[i, j] = buf[s + j]


def gather(buf: np.ndarray, starts: np.ndarray, width: int) -> np.ndarray:
    """The ``width`` bytes at each of ``starts``, one row each: records to view with a dtype."""
    out = np.empty((len(starts), width), dtype=np.uint8)
    _gather(buf, starts, width, out)
    return out
