"""Outputs as one transaction: every file of a run is written to a temporary beside its target
and renamed into place only when all of them are complete.

- :func:`~imucal.io.targets.check_output_path` refuses, before any work, a target imucal must
  not replace (a device, a FIFO, /dev/stdout, a directory, a read-only file, an input, ...).
- :class:`Transaction` locks the set of outputs against another imucal run (an ``fcntl`` lock
  on a small lock file beside each target, removed afterwards), hands out short temporary
  names, and commits: the renames run with SIGINT/SIGTERM/SIGHUP held back, and if one fails
  the targets already renamed get their previous content back (a hard link kept as backup).
  Any error or interrupt before that removes every temporary and touches no previous file; a
  SIGKILL leaves hidden ``.imucal-*`` temporaries, which the next run on them removes.
- ``owned`` targets (a file imucal names itself, such as a table's gyroscope sidecar) are
  replaced or removed only when imucal can prove it wrote them: commit leaves a record of each
  beside it (``.imucal-TAG.owner``, the file's SHA-256 as ``sha256sum`` writes it), and a run
  finding such a name taken by any other file refuses before any work.
- :func:`atomic_path`, :func:`write_atomic`: one file, for the library's own writers.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import secrets
import signal
import threading
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

from imucal.errors import ImucalError
from imucal.io import beside as bs
from imucal.io.beside import OWNER_SUFFIX, PREFIX, owner_record
from imucal.io.targets import check_output_path, refuse

__all__ = ["OWNER_SUFFIX", "PREFIX", "Transaction", "atomic_path", "check_output_path", "held_back",
           "io_problem", "owner_record", "write_atomic", "write_text_atomic"]

try:
    import fcntl
except ImportError:  # not POSIX: still one transaction, without the lock against another run
    fcntl = None

_HELD_BACK = tuple(getattr(signal, n) for n in ("SIGINT", "SIGTERM", "SIGHUP")
                   if hasattr(signal, n))
_RUST_IO = re.compile(r"\(os error (\d+)\)")  # how Rust's io::Error (polars, rerun) ends


# --- temporaries -------------------------------------------------------------------------------


def io_problem(e: BaseException) -> str | None:
    """The operating system's reason when ``e`` is a failed read or write (an OSError, or a
    Rust library's error that ends in "(os error N)"), else None."""
    if isinstance(e, OSError) and e.errno:
        return e.strerror or os.strerror(e.errno)
    m = _RUST_IO.search(str(e)) if isinstance(e, Exception) else None
    return os.strerror(int(m.group(1))) if m else None


@contextlib.contextmanager
def held_back() -> Iterator[None]:
    """SIGINT, SIGTERM and SIGHUP wait until the block is done, then take effect as usual.

    Python-level handlers, not a signal mask: a process-directed signal is delivered to any
    thread that does not block it (the libraries' threads), and Python then acts on it in the
    main thread at once whatever the main thread's mask."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    previous = {}
    for sig in _HELD_BACK:
        with contextlib.suppress(OSError, ValueError):
            previous[sig] = signal.signal(sig, lambda signum, frame: caught.append(signum))
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if caught:
            handler = previous.get(caught[0])
            if callable(handler):
                handler(caught[0], None)  # e.g. KeyboardInterrupt
            elif handler == signal.SIG_DFL:
                signal.raise_signal(caught[0])


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` on success, remove it on
    any error or interrupt. ``path`` is checked first (:func:`check_output_path`)."""
    target = check_output_path(path)
    tmp = bs.new_temp(target, tagged=False)
    try:
        yield tmp
        os.replace(tmp, target)
    except BaseException as e:
        bs.unlink(tmp)
        why = io_problem(e) if isinstance(e, Exception) and not isinstance(e, ImucalError) else None
        if why is not None:  # a full disk, say, and the file it stopped (issue 27)
            raise ImucalError(f"could not be written: {why}; the previous file, if any, is "
                              "unchanged", source=os.fspath(path)) from None
        raise


def write_atomic(path: str | os.PathLike, write: Callable[[Path], None]) -> None:
    with atomic_path(path) as tmp:
        write(tmp)


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    def _w(tmp: Path) -> None:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())

    write_atomic(path, _w)


# --- the transaction ---------------------------------------------------------------------------


@dataclass
class _Output:
    shown: str  # as the user named it (messages)
    target: Path  # the file a write reaches
    exclusive: bool = False  # never replace: commit fails if the name was taken meanwhile
    tmp: Path | None = None
    expected: bool = False  # tmp is a writer's sidecar, maybe never written (see expect)
    remove: bool = False  # commit removes a previous file of this name (a stale sidecar)
    removed: bool = False  # ... and there was one
    lock_fd: int | None = None
    lock: Path | None = None
    owned: str | None = None  # replaced or removed only if imucal wrote it: what it is
    record: _Output | None = None  # ... and the record that says so (see owner_record)
    seen: tuple | None = None  # the file found at the start of the run (see _identity)
    is_record: bool = False  # this output is another's record


class Transaction:
    """The outputs of one run: all delivered, or none changed.

    >>> with Transaction([out, rrd], inputs=[session]) as tx:    # checks and locks
    ...     save(tx.temp(out)); ...                              # every output to a temporary
    ...     tx.commit()                                          # all renamed, or none

    Leaving the block without :meth:`commit` (an error, Ctrl-C, SIGTERM) removes every
    temporary; the previous files stay byte-identical. ``exclusive`` targets are created, never
    replaced (a name imucal chose, not the user). ``owned`` targets, mapped to what they
    are ("the gyroscope table of cal.csv"), are names the user did not give: one taken by a
    file imucal cannot prove it wrote is refused when the block is entered."""

    def __init__(self, targets: Iterable[str | os.PathLike | None], *,
                 inputs: Iterable[str | os.PathLike | None] = (),
                 exclusive: Iterable[str | os.PathLike] = (),
                 owned: dict[str | os.PathLike, str] | None = None) -> None:
        ins = [i for i in inputs if i is not None]
        excl = {os.fspath(p) for p in exclusive}
        owned = {os.fspath(p): what for p, what in (owned or {}).items()}
        self._outputs: list[_Output] = []
        seen: dict[Path, str] = {}
        for t in targets:
            if t is None:
                continue
            shown = os.fspath(t)
            target = check_output_path(shown, ins)
            if target in seen:
                raise refuse(f"the same file is given for two outputs ({seen[target]} and "
                             f"{shown})", shown)
            seen[target] = shown
            out = _Output(shown, target, exclusive=shown in excl, owned=owned.get(shown))
            self._outputs.append(out)
            if out.owned is not None:
                rec = owner_record(target)
                out.record = _Output(os.fspath(rec), check_output_path(rec, ins),
                                     is_record=True)
                self._outputs.append(out.record)
        self.committed = False

    def __enter__(self) -> Transaction:
        try:
            # outputs, then owner records, each in path order: a busy one is named as given
            for out in sorted(self._outputs, key=lambda o: (o.is_record, str(o.target))):
                self._lock(out)
            for out in self._outputs:
                if out.owned is not None:
                    self._check_owned(out)
        except BaseException:
            self._release()
            raise
        return self

    def __exit__(self, *exc) -> None:
        with held_back():
            if not self.committed:
                for out in self._outputs:
                    bs.unlink(out.tmp)
                    out.tmp = None
            self._release()

    # -- locks --

    def _lock(self, out: _Output) -> None:
        if fcntl is None:
            return
        lock = out.target.parent / f"{PREFIX}{bs.tag(out.target)}.lock"
        while True:
            try:
                fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
            except OSError as e:
                raise refuse(f"cannot create a lock file beside it ({e.strerror})",
                             out.shown) from None
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as e:
                os.close(fd)
                if e.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                    raise ImucalError("in use by another imucal run", source=out.shown) from None
                raise
            # The holder removes its lock file before unlocking: locked a removed file? Again.
            try:
                here = os.stat(lock)
                mine = os.fstat(fd)
                if (here.st_dev, here.st_ino) == (mine.st_dev, mine.st_ino):
                    break
            except FileNotFoundError:
                pass
            os.close(fd)
        out.lock_fd, out.lock = fd, lock
        # Holding the lock, any temporary of this target is a killed run's leftover.
        for old in out.target.parent.glob(f"{PREFIX}{bs.tag(out.target)}-*"):
            bs.unlink(old)

    @staticmethod
    def _check_owned(out: _Output) -> None:
        """Refuse, before any work, to replace or remove a file the user did not name and
        imucal did not write (held under the lock: another run cannot be writing it)."""
        out.seen = bs.identity(out.target)
        if out.seen is not None and not bs.written_by_imucal(out.target):
            raise ImucalError(f"exists and imucal did not write it, but this run would replace "
                              f"or remove it ({out.owned}); move it away or choose another "
                              "output name", source=out.shown)

    def _release(self) -> None:
        for out in self._outputs:
            if out.lock_fd is not None:
                bs.unlink(out.lock)  # while still locked: see _lock
                os.close(out.lock_fd)
                out.lock_fd = out.lock = None

    # -- writing --

    def _find(self, path: str | os.PathLike) -> _Output:
        key = os.fspath(path)
        for out in self._outputs:
            if key in (out.shown, str(out.target)):
                return out
        raise KeyError(f"{key} is not an output of this transaction")

    def temp(self, path: str | os.PathLike) -> Path:
        """The temporary that ``path``'s new content goes to (created empty, short name, the
        target's suffix, the permissions of the file it will replace)."""
        out = self._find(path)
        if out.tmp is None:
            out.tmp = bs.new_temp(out.target, tagged=True)
        return out.tmp

    @contextlib.contextmanager
    def writing(self, path: str | os.PathLike) -> Iterator[Path]:
        """:meth:`temp` around a writer: a failed write (full disk, file too large, I/O error)
        becomes a one-line error naming ``path``."""
        out = self._find(path)
        with self._failing_as(out):
            yield self.temp(path)

    @contextlib.contextmanager
    def _failing_as(self, out: _Output) -> Iterator[None]:
        try:
            yield
        except ImucalError as e:
            if e.source and Path(e.source).name.startswith(PREFIX):  # our temporary: name
                raise ImucalError(e.problem.replace("the previous file, if any, is unchanged",
                                                    "no output was changed"),
                                  source=out.shown, field=e.field) from None
            raise
        except Exception as e:
            why = io_problem(e)
            if why is None:
                raise
            raise ImucalError(f"could not be written: {why}; no output was changed",
                              source=out.shown) from None

    def expect(self, path: str | os.PathLike, written: Path) -> None:
        """``path``'s new content is whatever a writer leaves at ``written`` (beside a
        temporary: a sidecar file). Registered before the writer runs, so that a failure
        removes it; if nothing is there at commit, commit removes a previous ``path``."""
        out = self._find(path)
        bs.unlink(out.tmp)
        out.tmp, out.expected = written, True

    def shown(self, path: str | os.PathLike) -> str:
        return self._find(path).shown

    @property
    def removed(self) -> list[str]:
        """The previous files commit removed (see :meth:`expect`)."""
        return [o.shown for o in self._outputs if o.removed and not o.is_record]

    # -- commit --

    def commit(self) -> None:
        """Rename every temporary onto its target, all or none; first flush each to the disk
        (a full disk may only show there)."""
        for out in self._outputs:
            if out.is_record:
                continue  # made with its file, below
            if out.tmp is not None and out.expected and not out.tmp.exists():
                out.tmp, out.remove = None, True
            elif out.tmp is None:
                raise RuntimeError(f"output not written: {out.shown}")
            else:
                with self._failing_as(out):
                    bs.fsync(out.tmp)
                    os.chmod(out.tmp, bs.mode_for(out.target))
            if out.record is not None:
                self._prepare_record(out)
        with held_back():
            backups: list[tuple[_Output, Path | None, bool]] = []
            try:
                for out in self._outputs:
                    backups.append((out, *self._backup(out)))
                    self._put(out)
            except OSError as e:
                self._roll_back(backups)
                raise ImucalError(f"could not be put in place: {e.strerror or e}; no output "
                                  "was changed", source=backups[-1][0].shown) from None
            finally:
                for _, b, _ in backups:
                    bs.unlink(b)
            self.committed = True
            for d in {o.target.parent for o in self._outputs}:
                with contextlib.suppress(OSError):
                    bs.fsync(d)

    def _prepare_record(self, out: _Output) -> None:
        """The record of an owned output goes with it: written for a new file, removed with a
        removed one. A file put at the name by something else during the run is refused."""
        if bs.identity(out.target) != out.seen:
            raise ImucalError("was changed by something else during the run; no output was "
                              "changed", source=out.shown)
        rec = out.record
        bs.unlink(rec.tmp)
        rec.tmp = None
        if out.remove:
            rec.remove = True
            return
        rec.tmp = bs.new_temp(rec.target, tagged=True)
        with self._failing_as(rec):
            with open(rec.tmp, "wb") as f:
                f.write(bs.record_line(out.tmp, out.target.name))
                f.flush()
                os.fsync(f.fileno())

    @staticmethod
    def _backup(out: _Output) -> tuple[Path | None, bool]:
        """A hard link to the previous file (the way back if a later rename fails), and
        whether there was one."""
        if not out.target.exists():
            return None, False
        b = out.target.parent / f"{PREFIX}{bs.tag(out.target)}-{secrets.token_hex(4)}.bak"
        try:
            os.link(out.target, b)
        except OSError:  # no hard links here: the rename still happens, without a way back
            return None, True
        return b, True

    @staticmethod
    def _put(out: _Output) -> None:
        if out.remove:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(out.target)
                out.removed = True
        elif out.exclusive:
            os.link(out.tmp, out.target)  # EEXIST if the name was taken meanwhile
            bs.unlink(out.tmp)
        else:
            os.replace(out.tmp, out.target)
        out.tmp = None

    @staticmethod
    def _roll_back(done: list[tuple[_Output, Path | None, bool]]) -> None:
        for out, backup, existed in reversed(done):
            with contextlib.suppress(OSError):
                if backup is not None:
                    os.replace(backup, out.target)
                elif not existed and out.tmp is None and not out.remove:  # made by this commit
                    os.unlink(out.target)
