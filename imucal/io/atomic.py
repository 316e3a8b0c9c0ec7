"""Atomic output: write to a temporary file beside the target, then rename over it.

An interrupted run (Ctrl-C, kill) leaves either the previous file or the new one, never a
partial file; the temporary is removed on any error.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path

from imucal.errors import ImucalError


def check_output_path(path: str | os.PathLike, inputs: tuple[str | os.PathLike, ...] = ()) -> Path:
    """Refuse an output that would overwrite an input or land in a missing directory."""
    out = Path(path)
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir():
        raise ImucalError(f"the directory {str(parent)!r} does not exist", source=str(out),
                          field="output path")
    for inp in inputs:
        if inp and Path(inp).exists() and out.exists() and os.path.samefile(out, inp):
            raise ImucalError("the output path is an input file; refusing to overwrite it",
                              source=str(out), field="output path")
        if inp and Path(inp).resolve() == out.resolve():
            raise ImucalError("the output path is an input file; refusing to overwrite it",
                              source=str(out), field="output path")
    return out


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path in the target's directory; rename it onto ``path`` on success."""
    target = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp",
                               dir=target.parent if str(target.parent) else ".")
    os.close(fd)
    tmp_path = Path(tmp)
    # mkstemp makes the file private (0600); give it the permissions a plain open() would.
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp_path, 0o666 & ~umask)
    try:
        yield tmp_path
        os.replace(tmp_path, target)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp_path.unlink()
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
