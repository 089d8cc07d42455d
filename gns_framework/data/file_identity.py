"""Whether a data file is still the one a reader opened: truncated, rewritten or replaced files are named, not read.

A memory-mapped file truncated under its reader makes the kernel end the reader with
SIGBUS, with no message; one rewritten in place feeds changed values. Readers record a
file's identity when they open it and check it before reading on (:mod:`.lazy`,
:mod:`.npz_mapping`).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple, TypeVar

from ..errors import DatasetError


class DatasetChanged(DatasetError):
    """A data file changed under its reader (truncated, rewritten or replaced)."""


class FileIdentity(NamedTuple):
    """What tells a file apart from a changed one: device and inode, size, modification time (ns)."""

    device: int
    inode: int
    size: int
    modified_ns: int

    @classmethod
    def of(cls, info: os.stat_result) -> FileIdentity:
        return cls(info.st_dev, info.st_ino, info.st_size, info.st_mtime_ns)

    @classmethod
    def of_path(cls, path: str | Path) -> FileIdentity | None:
        """The identity of the file at ``path`` now, None where there is none."""
        try:
            return cls.of(os.stat(path))
        except OSError:
            return None

    def check(self, path: str | Path) -> None:
        """Raise DatasetChanged naming ``path`` and what changed, unless it is still this file, unchanged."""
        now = FileIdentity.of_path(path)
        if now == self:
            return
        if now is None:
            change = "it is gone"
        elif (now.device, now.inode) != (self.device, self.inode):
            change = "another file replaced it"
        elif now.size != self.size:
            change = f"its size went from {self.size} to {now.size} bytes" + (
                " (truncated?)" if now.size < self.size else ""
            )
        else:
            change = "it was rewritten (modification time changed)"
        raise DatasetChanged(
            f"{path}: changed while it was being read ({change}); stopped rather than read it: put the data back as "
            "it was (or train on a copy), then resume"
        )


Read = TypeVar("Read", bound=Callable)


def unchanged_reads(read: Read, source: str | Path) -> Read:
    """``read`` checking, before and after each call, that ``source`` is still the file it was when this was made.

    A split rewritten between two reads would mix old and new trajectories; one rewritten
    during a read, old and new values. A source that is not a file is not checked.
    """
    identity = FileIdentity.of_path(source)
    if identity is None:
        return read

    def checked(*args):
        identity.check(source)
        value = read(*args)
        identity.check(source)
        return value

    return checked  # type: ignore[return-value]  # the same signature as read
