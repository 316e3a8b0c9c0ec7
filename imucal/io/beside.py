"""The hidden files imucal keeps beside a target (:mod:`imucal.io.atomic`): their short names,
the temporaries a write goes to, and the record that imucal wrote a file the user did not name
(``.imucal-TAG.owner``: its SHA-256 as ``sha256sum`` writes it, so that a later run replaces or
removes that file only while it is, byte for byte, what imucal left there)."""

from __future__ import annotations

import contextlib
import hashlib
import os
import secrets
import stat
from pathlib import Path

PREFIX = ".imucal-"  # temporaries, backups and lock files: hidden, and short whatever the target
OWNER_SUFFIX = ".owner"  # the record that imucal wrote an ``owned`` target (kept with it)


def tag(target: Path) -> str:
    """A short name of one target, the same in every run: its lock file's and its
    temporaries' (so a run holding the lock knows a killed run's leftovers)."""
    return hashlib.sha256(os.fsencode(target.name)).hexdigest()[:12]


def mode_for(target: Path) -> int:
    """A replacement keeps the permissions of the file it replaces; a new file gets what a
    plain open() would give it."""
    with contextlib.suppress(OSError):
        return stat.S_IMODE(os.stat(target).st_mode)
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


def new_temp(target: Path, *, tagged: bool) -> Path:
    """An empty file beside ``target``: ``.imucal-TAG-RANDOM.csv`` for a transaction (the
    target's suffix, which writers read the format from; TAG names the target, see
    :func:`tag`), ``.imucal-RANDOM.tmp`` for :func:`atomic_path`."""
    suffix = target.suffix if 0 < len(target.suffix) <= 16 else ""
    mode = mode_for(target)
    while True:
        rand = secrets.token_hex(4)
        name = f"{tag(target)}-{rand}{suffix}" if tagged else f"{rand}.tmp"
        tmp = target.parent / f"{PREFIX}{name}"
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o600)
        except FileExistsError:
            continue
        try:
            os.fchmod(fd, mode)
        finally:
            os.close(fd)
        return tmp


def fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def unlink(path: Path | None) -> None:
    if path is not None:
        with contextlib.suppress(OSError):
            os.unlink(path)



def owner_record(target: Path) -> Path:
    """Where the record that imucal wrote ``target`` lives (short whatever the name)."""
    return target.parent / f"{PREFIX}{tag(target)}{OWNER_SUFFIX}"


def record_line(path: Path, name: str) -> bytes:
    """``path``'s SHA-256 as sha256sum prints it, for the file called ``name``."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(1 << 20):
            h.update(block)
    return h.hexdigest().encode() + b"  " + os.fsencode(name) + b"\n"


def written_by_imucal(target: Path) -> bool:
    """Whether ``target`` is, byte for byte, the file an imucal run left there (its record
    beside it says so)."""
    try:
        record = owner_record(target).read_bytes()
        return stat.S_ISREG(os.lstat(target).st_mode) and record == record_line(target,
                                                                               target.name)
    except OSError:
        return False


def identity(path: Path) -> tuple | None:
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return None
    return st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns
