"""Large signals kept in a temporary file the process maps, not in its own memory (issue 12).

A 6-hour recording at 1 kHz is 1.2 GB of float64; held in the process, every worker of a
batch needs that much RAM before it computes anything. Here each large array is a shared
mapping of a temporary file (unlinked at once: nothing is left behind, even after a crash). The
arrays are ordinary numpy arrays to every stage, with the same values, so every result is the
same to the bit. The kernel caches the file; a watcher thread drops the process's mapped
pages whenever its resident memory passes a budget (``madvise(MADV_DONTNEED)``: the data stay
in the page cache or on disk and are read back on the next access), so what the process holds
is bounded by what a stage is working on, not by the length of the recording.
"""

from __future__ import annotations

import mmap
import os
import sys
import tempfile
import threading
import weakref
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from imucal.errors import ImucalError

# Arrays from this size up are mapped (64 MB: 44 minutes of a 3-axis 1 kHz signal); smaller
# ones cost less than the file and the watcher.
SPILL_ABOVE_BYTES = 64 << 20
# Resident memory above which the watcher drops mapped pages. Dropped pages cost a minor fault
# when read again (about 0.3 s per GB from the page cache), so a lower budget trades a little
# time for room; what stays above it is the stages' own working memory (a chunk, a slab). At
# 6 h of 1 kHz: peak RSS 1.16-1.28 GB with 1 GiB here.
RESIDENT_BUDGET_BYTES = 512 << 20
# How often the watcher looks (s): at memory bandwidth a stage touches a few hundred MB of
# mapped pages between two looks at most.
WATCH_INTERVAL_S = 0.02


@dataclass(frozen=True)
class SpillPolicy:
    """Where and from which size a session's arrays are mapped from a temporary file.

    ``directory`` None is the system's temporary directory (``TMPDIR``); ``above_bytes`` None
    never maps (every array in memory, as a small session is).
    """

    directory: Path | None = None
    above_bytes: int | None = SPILL_ABOVE_BYTES
    resident_budget_bytes: int = RESIDENT_BUDGET_BYTES

    def where(self) -> Path:
        return Path(self.directory) if self.directory is not None else Path(tempfile.gettempdir())


IN_MEMORY = SpillPolicy(above_bytes=None)


class Spill:
    """Allocates a session's arrays: in memory below the policy's size, else mapped from a
    temporary file. Keeps account of what it mapped for the notes."""

    def __init__(self, policy: SpillPolicy = SpillPolicy(), source: str = "") -> None:
        self.policy, self.source = policy, source
        self.mapped_bytes = 0
        self._watcher: _Watcher | None = None

    def empty(self, shape: tuple[int, ...], order: str = "C") -> np.ndarray:
        """An uninitialised float64 array of ``shape``, mapped when large."""
        nbytes = int(np.prod(shape, dtype=np.int64)) * 8
        above = self.policy.above_bytes
        if above is None or nbytes < above or nbytes == 0:
            return np.empty(shape, dtype=np.float64, order=order)
        m = _mapped_file(self.policy.where(), nbytes, self.source)
        if self._watcher is None:
            self._watcher = _Watcher(self.policy.resident_budget_bytes)
        self._watcher.watch(m)
        self.mapped_bytes += nbytes
        flat = np.frombuffer(m, dtype=np.float64)  # keeps the mapping alive while it lives
        return flat.reshape(shape, order=order)

    def release(self, a: np.ndarray) -> None:
        """Drop the resident pages of ``a``'s mapping now, not when the process passes its
        budget: for an array written once and read seldom (a long text file's columns, once
        parsed). The data stay in the page cache or on disk; nothing for an array in memory."""
        base = a
        while isinstance(base, np.ndarray):
            base = base.base
        if isinstance(base, memoryview):
            base = base.obj
        if isinstance(base, mmap.mmap) and self._watcher is not None and self._watcher.enabled:
            base.madvise(mmap.MADV_DONTNEED)

    def note(self) -> str | None:
        """Where the signals are held, for the report; None when all are in memory."""
        if not self.mapped_bytes:
            return None
        budget = self.policy.resident_budget_bytes
        return (f"{self.mapped_bytes / 1e6:.0f} MB of signals mapped from a temporary file in "
                f"{self.policy.where()}, at most {budget / 2**30:.3g} GiB resident "
                "(--spill-dir to move it)")


def _mapped_file(directory: Path, nbytes: int, source: str) -> mmap.mmap:
    """A shared, writable mapping of a new temporary file of ``nbytes``, already unlinked.
    The space is reserved up front: a full disk is a clear error here, not a crash (SIGBUS)
    when a page is first written."""
    try:
        fd, name = tempfile.mkstemp(prefix="imucal-", suffix=".spill", dir=directory)
    except OSError as e:
        raise ImucalError(f"cannot create a temporary file in {directory} for the signals "
                          f"({e.strerror}); set --spill-dir or TMPDIR to a writable folder",
                          source=source, field="spill") from None
    try:
        os.unlink(name)
        try:
            if hasattr(os, "posix_fallocate"):
                os.posix_fallocate(fd, 0, nbytes)
            else:
                os.ftruncate(fd, nbytes)
        except OSError as e:
            raise ImucalError(f"cannot reserve {nbytes / 1e6:.0f} MB in {directory} for the "
                              f"signals ({e.strerror}); free some space or set --spill-dir "
                              "(or TMPDIR) to a folder with room", source=source,
                              field="spill") from None
        return mmap.mmap(fd, nbytes, mmap.MAP_SHARED, mmap.PROT_READ | mmap.PROT_WRITE)
    finally:
        os.close(fd)  # the mapping keeps the file open


def _resident_bytes() -> int | None:
    """The process's resident set (bytes), from /proc; None where there is none."""
    try:
        with open("/proc/self/statm", "rb") as fh:
            return int(fh.read().split()[1]) * mmap.PAGESIZE
    except (OSError, ValueError, IndexError):
        return None


class _Watcher:
    """A daemon thread that drops the mapped pages of live mappings whenever the process's
    resident memory passes ``budget``. It ends by itself once every mapping it watches is
    gone (the arrays were freed), so it holds nothing alive and needs no closing."""

    def __init__(self, budget: int) -> None:
        self.budget = budget
        self.maps: list[weakref.ref[mmap.mmap]] = []
        self.lock = threading.Lock()
        self.thread: threading.Thread | None = None
        # Linux drops a shared file mapping's pages without losing data (dirty pages stay in
        # the page cache); elsewhere MADV_DONTNEED may mean otherwise: leave it to the OS.
        self.enabled = sys.platform.startswith("linux") and hasattr(mmap, "MADV_DONTNEED")

    def watch(self, m: mmap.mmap) -> None:
        if not self.enabled:
            return
        with self.lock:
            self.maps.append(weakref.ref(m))
            if self.thread is None or not self.thread.is_alive():
                self.thread = threading.Thread(target=self._run, name="imucal-spill",
                                               daemon=True)
                self.thread.start()

    def _run(self) -> None:
        wait = threading.Event().wait
        while True:
            wait(WATCH_INTERVAL_S)
            if not self._look():
                return

    def _look(self) -> bool:
        """Trim the live mappings if the process is over budget; False once none is left.
        (A function of its own: the mappings it names are released when it returns.)"""
        with self.lock:
            live = [r() for r in self.maps]
            self.maps = [r for r, m in zip(self.maps, live) if m is not None]
            if not self.maps:
                self.thread = None
                return False
        rss = _resident_bytes()
        if rss is not None and rss > self.budget:
            for m in live:
                if m is not None:
                    m.madvise(mmap.MADV_DONTNEED)
        return True


# --- whole-signal steps of the loader, a chunk of rows at a time into an allocated array ------

Empty = Callable[..., np.ndarray]
_ROWS = 1 << 16


def elementwise(f: Callable[..., object], x: np.ndarray, empty: Empty) -> np.ndarray:
    """``f(x)`` for an elementwise ``f(x, out=...)`` (a ufunc), computed a chunk of rows at a
    time into ``empty(x.shape)``: the same values as ``f(x)``, without a second signal-sized
    array in memory when ``empty`` maps."""
    out = empty(x.shape)
    for lo in range(0, len(x), _ROWS):
        f(x[lo:lo + _ROWS], out=out[lo:lo + _ROWS])
    return out


def contiguous(x: np.ndarray, store: Spill) -> np.ndarray:
    """``np.ascontiguousarray(x, dtype=np.float64)``: ``x`` itself when it is already one, else
    a copy made a chunk of rows at a time into ``store``'s array."""
    if x.dtype == np.float64 and x.flags.c_contiguous:
        return x
    out = store.empty(x.shape)
    for lo in range(0, len(x), _ROWS):
        out[lo:lo + _ROWS] = x[lo:lo + _ROWS]
    return out
