"""The input paths a session is read from, checked before anything is read: a file that is
there, readable as a file (not a device or a FIFO, whose size says nothing), not too large, and
a gyroscope's file that does not contradict the rest of the command (issue 27)."""

from __future__ import annotations

import os
import stat
from pathlib import Path

from imucal.errors import ImucalError
from imucal.io.readers import display_name


def check_file(path: Path, log: bool, max_bytes: int) -> None:
    """A file that exists and can be read, of at most ``max_bytes``; a log of many streams
    (``log``) may be a ROS 2 bag's folder, and may be larger than a table, as only its chosen
    streams are read."""
    name = display_name(path)
    try:
        st = path.stat()
    except FileNotFoundError:
        where = "" if str(path) == name else f" (looked at {path})"
        raise ImucalError(f"file not found{where}", source=name) from None
    except OSError as exc:
        raise ImucalError(f"cannot access the file ({exc.strerror})", source=name) from None
    refuse_special(st.st_mode, name)
    if log:
        return
    if path.is_dir():
        raise ImucalError("is a directory; expected a data file", source=name)
    if st.st_size == 0:
        raise ImucalError("the file is empty; expected IMU samples", source=name)
    if st.st_size > max_bytes:
        raise ImucalError(f"the file is {st.st_size / 2**30:.1f} GiB; files over 2 GiB are not "
                          "loaded (split the recording)", source=name)


def check_gyro_file(paths: list[Path], acc_only: bool) -> None:
    """Contradictions of a gyroscope's file, refused before anything is read (issue 27):
    --acc-only with one, and the session's own file given again as its gyroscope."""
    if len(paths) < 2:
        return
    if acc_only:
        raise ImucalError(f"--acc-only calibrates the accelerometer alone, but --gyro "
                          f"{display_name(paths[1])} names a gyroscope; give one or the other",
                          source=display_name(paths[0]), field="--gyro")
    try:
        same = os.path.samefile(paths[0], paths[1])
    except OSError:
        same = False
    if same:
        raise ImucalError("is the session file itself; a file with both sensors needs "
                          "no --gyro, and a two-file session names the gyroscope's file",
                          source=display_name(paths[1]), field="--gyro")


def refuse_special(mode: int, name: str) -> None:
    """A path that is neither a regular file nor a directory, refused saying what it is: its
    size is 0 whatever it carries (it is not "empty"), and a recording is read more than once
    (its format, its hash, its columns), so it must be a file on disk (issue 27)."""
    for test, what in ((stat.S_ISCHR, "character device (such as /dev/zero or /dev/urandom)"),
                       (stat.S_ISBLK, "block device"), (stat.S_ISFIFO, "FIFO (named pipe)"),
                       (stat.S_ISSOCK, "socket")):
        if test(mode):
            raise ImucalError(f"is a {what}, not a file of samples; save the recording to a "
                              "file first", source=name)
