"""Atomic file writes: a reader never sees a half-written file, a failed write keeps the old one, and a finished
one survives a power loss."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path


@contextlib.contextmanager
def atomic_path(path: str | Path, suffix: str = "") -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it over ``path`` only on success.

    The file's data is flushed to disk before the rename and the directory after it:
    the rename is an entry of the directory, which without its own fsync can be lost
    in a power cut, leaving the old file (or none) behind a run that reported success.

    ``suffix`` keeps a file extension some writers insist on (``np.savez`` adds ``.npz``).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=f".tmp{suffix}", dir=path.parent)
    try:
        # mkstemp makes the file 0600: a new file follows the umask like any other, a replaced one keeps its mode.
        # lstat: a link at ``path`` is replaced by the file (its target is never written), so its target's mode is not
        # ours.
        replaced = path.exists() and not path.is_symlink()
        os.fchmod(fd, os.lstat(path).st_mode & 0o7777 if replaced else 0o666 & ~process_umask())
    finally:
        os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        with open(tmp_path, "rb+") as handle:
            os.fsync(handle.fileno())
        os.replace(tmp_path, path)
        fsync_directory(path.parent)
    finally:
        tmp_path.unlink(missing_ok=True)


def process_umask() -> int:
    """The process's umask: from /proc where Linux gives it, else by setting it and putting it back."""
    try:
        with open("/proc/self/status", "rb") as status:
            for line in status:
                if line.startswith(b"Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def fsync_directory(directory: str | Path) -> None:
    """Flush ``directory``'s entries (files renamed into or out of it) to disk."""
    fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_text_atomic(path: str | Path, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text)
