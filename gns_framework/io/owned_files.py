"""Files a command owns inside its output folder are opened there and nowhere else.

A run folder copied from a colleague (or unpacked from an archive) may hold a symbolic
link where a run's file belongs: ``metrics.jsonl -> ~/.bashrc``. Opening it the usual
way follows the link, and a resumed training would append its metrics to the target or
truncate it. Every file a command writes inside a folder it owns is opened here with
``O_NOFOLLOW`` (the kernel refuses a link as the last part of the path, with no window
between a check and the open) and must be a regular file with no other name (a hard link
to a file elsewhere is the same trap). A refusal is one line naming the file and what it
points to; nothing is written.
"""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path
from typing import IO

from ..errors import GnsError

_FLAGS = {
    "w": os.O_WRONLY | os.O_CREAT,
    "a": os.O_WRONLY | os.O_CREAT | os.O_APPEND,
    "r+": os.O_RDWR | os.O_CREAT,
}


class LinkRefused(GnsError):
    """A file a command owns is a symbolic link, a hard link or not a regular file."""


def describe_link(path: Path) -> str:
    """Where the link at ``path`` points, for an error message."""
    try:
        return f"a symbolic link to {os.readlink(path)}"
    except OSError:
        return "a symbolic link"


def refuse_link(path: str | Path, what: str) -> None:
    """Raise LinkRefused when ``path`` (a file or folder the command owns) is a symbolic link."""
    path = Path(path)
    if path.is_symlink():
        raise LinkRefused(
            f"{path}: the {what} is {describe_link(path)}; gns never writes through a link in a folder it owns "
            "(remove the link, or write into another folder)"
        )


def open_owned_fd(path: str | Path, mode: str, what: str, permissions: int = 0o666) -> int:
    """An OS file descriptor of ``path`` opened for ``mode`` ('w', 'a' or 'r+', created when missing), never through a
    link.

    ``what`` names the file in the refusal ("run folder's lock", "metrics file").
    """
    path = Path(path)
    flags = _FLAGS[mode] | os.O_NOFOLLOW | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags, permissions)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            refuse_link(path, what)
        if exc.errno == errno.ENXIO:  # a FIFO with no reader: O_NONBLOCK keeps us from waiting for one
            raise LinkRefused(f"{path}: the {what} is not a regular file (a named pipe)") from None
        raise GnsError(f"{path}: cannot open the {what}: {exc.strerror or exc}") from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise LinkRefused(f"{path}: the {what} is not a regular file; gns writes only regular files it owns")
        if info.st_nlink > 1:
            raise LinkRefused(
                f"{path}: the {what} has {info.st_nlink} names (a hard link to a file elsewhere?); gns never writes "
                "into a file that is also somewhere else (copy the folder without hard links, or remove the file)"
            )
        os.set_blocking(fd, True)
        if mode == "w":  # truncated only once it is known to be ours (O_TRUNC would empty a hard link's target)
            os.ftruncate(fd, 0)
    except BaseException:
        os.close(fd)
        raise
    return fd


def open_owned(path: str | Path, mode: str, what: str) -> IO:
    """``open(path, mode)`` for a file the command owns ('w', 'a', 'wb', 'ab'), never through a link."""
    fd = open_owned_fd(path, mode.rstrip("b"), what)
    return os.fdopen(fd, mode) if mode.endswith("b") else os.fdopen(fd, mode, encoding="utf-8")


def write_owned_text(path: str | Path, text: str, what: str) -> None:
    """Replace the contents of a file the command owns, never through a link."""
    with open_owned(path, "w", what) as handle:
        handle.write(text)
