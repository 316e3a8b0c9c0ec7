"""Which output paths imucal may write: checked before any work (:func:`check_output_path`).

A run replaces its outputs by renaming a finished temporary over them (:mod:`imucal.io.atomic`).
That is only right for a regular file the user may write: renaming over ``/dev/null``, a FIFO
or ``/dev/stdout`` would replace the special file itself, and over a read-only file would undo
the user's own protection. Symbolic links are followed (the file they name is written, the link
stays).
"""

from __future__ import annotations

import os
import stat
from collections.abc import Iterable
from pathlib import Path

from imucal.errors import ImucalError

FIELD = "output path"


def refuse(why: str, shown: str) -> ImucalError:
    return ImucalError(why, source=shown, field=FIELD)


def _follow(raw: str, shown: str) -> Path:
    """The file a write to ``raw`` would reach: symbolic links followed one by one (a link
    into /proc, as /dev/stdout is, names another process's open file: refused)."""
    cur = os.path.abspath(raw)
    for _ in range(40):  # Linux's own limit on links in a path
        if cur.startswith("/proc/"):
            raise refuse("is a process's open file (such as /dev/stdout), not a regular file; "
                         "name a file to write", shown)
        if not os.path.islink(cur):
            parent = os.path.realpath(os.path.dirname(cur))
            return Path(parent) / os.path.basename(cur)
        cur = os.path.abspath(os.path.join(os.path.dirname(cur), os.readlink(cur)))
    raise refuse("is a loop of symbolic links", shown)


def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISCHR, "character device"), (stat.S_ISBLK, "block device"),
                       (stat.S_ISFIFO, "FIFO (named pipe)"), (stat.S_ISSOCK, "socket"),
                       (stat.S_ISDIR, "directory")):
        if test(mode):
            return name
    return "special file"


def _name_max(directory: Path) -> int:
    try:
        return int(os.pathconf(directory, "PC_NAME_MAX"))
    except (OSError, ValueError):
        return 255


def _same(a: Path, inp: str) -> bool:
    try:
        if a.exists() and os.path.samefile(a, inp):
            return True
    except OSError:
        pass
    return os.path.realpath(inp) == str(a)


def check_output_path(path: str | os.PathLike, inputs: Iterable[str | os.PathLike | None] = ()
                      ) -> Path:
    """Refuse a target imucal must not replace: ``-``, an empty name, a name ending in ``/``, a
    directory, anything not a regular file (device, FIFO, socket, /dev/stdout), a read-only
    file, a name longer than its file system allows, a missing or unwritable directory, an
    input. Return the file a write reaches (symbolic links followed)."""
    raw = os.fspath(path)
    shown = raw
    if raw == "-":
        raise refuse("standard output is not an output imucal writes to; name a file", shown)
    if not raw:
        raise refuse("is empty; expected a file name", "''")
    if raw.endswith(("/", "/.", "/..")) or os.path.basename(raw) in (".", ".."):
        raise refuse("names a directory; expected a file name", shown)
    target = _follow(raw, shown)
    parent = target.parent
    if not parent.is_dir():
        raise ImucalError(f"the directory {str(Path(raw).parent)!r} does not exist",
                          source=shown, field=FIELD)
    size, limit = len(os.fsencode(target.name)), _name_max(parent)
    if size > limit:
        raise refuse(f"the file name is {size} bytes long; this file system allows {limit}",
                     shown)
    try:
        st = os.stat(target)
    except FileNotFoundError:
        st = None
    except OSError as e:
        raise refuse(f"cannot be inspected ({e.strerror})", shown) from None
    if st is not None:
        if stat.S_ISDIR(st.st_mode):
            raise refuse("is a directory; expected a file name", shown)
        if not stat.S_ISREG(st.st_mode):
            raise refuse(f"is a {_kind(st.st_mode)}, not a regular file; refusing to replace "
                         "it", shown)
        # root passes os.access: the file's own write bits say what its owner allowed.
        if not (st.st_mode & 0o222) or not os.access(target, os.W_OK):
            raise refuse("is read-only; refusing to replace it (make it writable, or name "
                         "another file)", shown)
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ImucalError(f"the directory {str(parent)!r} is not writable", source=shown,
                          field=FIELD)
    for inp in inputs:
        if inp is not None and str(inp) and _same(target, os.fspath(inp)):
            raise refuse("the output path is an input file; refusing to overwrite it", shown)
    return target
