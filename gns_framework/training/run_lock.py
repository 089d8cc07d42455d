"""One writer per run folder: ``gns train`` holds an OS lock on ``<run>/.gns-train.lock`` for the whole run.

The lock is ``fcntl.flock`` on a file that records its holder (pid, host, since
when, command). The kernel drops it when the holder's process ends however it
ends (kill -9 included), so a lock left by a process that is gone is simply taken
over; the recorded holder only serves the message a second writer gets. The file
is removed when the lock is released, so a folder whose run could not start keeps
no trace of it.
"""

from __future__ import annotations

import contextlib
import datetime
import errno
import fcntl
import json
import os
import socket
import sys
from collections.abc import Iterator
from pathlib import Path

from ..errors import GnsError
from ..io.owned_files import open_owned_fd
from ..io.run_folder import RunFolder


class RunFolderBusy(GnsError):
    """Another process is writing into the run folder."""


class RunFolderLock:
    """The lock of one run folder, held from :meth:`acquire` until :meth:`release`."""

    def __init__(self, run_dir: str | Path):
        self.run_dir = Path(run_dir)
        self.path = RunFolder(self.run_dir).lock
        self._fd: int | None = None
        self._created_dir = False

    def acquire(self) -> RunFolderLock:
        if not self.run_dir.exists():
            self._created_dir = True
        try:
            self.run_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise GnsError(f"{self.run_dir}: cannot create the run folder: {exc.strerror or exc}") from None
        while True:
            # Never through a link: a lock linked to a user's file would be truncated and overwritten below.
            fd = open_owned_fd(self.path, "r+", "run folder's lock")
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as exc:
                os.close(fd)
                if exc.errno not in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):
                    raise GnsError(f"{self.path}: cannot lock the run folder: {exc.strerror or exc}") from None
                raise RunFolderBusy(
                    f"{self.run_dir}: another gns train is writing into this run folder "
                    f"({describe(read_holder(self.path))}; "
                    f"lock {self.path}): wait until it ends, or train into another folder with --out"
                ) from None
            # The holder before us may have removed the file between our open and our flock: then we hold the
            # lock of a file no longer there, and must lock the one at the path.
            try:
                same = os.path.samestat(os.fstat(fd), os.stat(self.path))
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        stale = read_holder_fd(fd)
        if stale:
            print(
                f"gns train: {self.run_dir}: taking over the lock of a writer that is gone ({describe(stale)})",
                file=sys.stderr,
            )
        holder = {
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "since": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
            "command": " ".join(sys.argv)[:500],
        }
        os.ftruncate(fd, 0)
        os.pwrite(fd, (json.dumps(holder) + "\n").encode(), 0)
        os.fsync(fd)
        self._fd = fd
        try:
            RunFolder(self.run_dir).refuse_links()
        except BaseException:
            self.release()
            raise
        return self

    def release(self) -> None:
        if self._fd is None:
            return
        fd, self._fd = self._fd, None
        # Removed while still held: a writer that opened it meanwhile finds it gone and locks a new file.
        with contextlib.suppress(OSError):
            os.unlink(self.path)
        os.close(fd)
        if self._created_dir:
            with contextlib.suppress(OSError):
                self.run_dir.rmdir()  # only when empty: the run could not start and left nothing

    def __enter__(self) -> RunFolderLock:
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


@contextlib.contextmanager
def run_folder_lock(run_dir: str | Path, take: bool = True) -> Iterator[RunFolderLock | None]:
    """Hold ``run_dir``'s lock for the block (nothing when ``take`` is false: the other ranks of a job)."""
    if not take:
        yield None
        return
    with RunFolderLock(run_dir) as lock:
        yield lock


def read_holder(path: Path) -> dict:
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)  # a link is not read: ELOOP
    except OSError:
        return {}
    try:
        return read_holder_fd(fd)
    except OSError:
        return {}
    finally:
        os.close(fd)


def read_holder_fd(fd: int) -> dict:
    return _parse(os.pread(fd, 4096, 0))


def _parse(data: bytes) -> dict:
    try:
        holder = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, ValueError):
        return {}
    return holder if isinstance(holder, dict) else {}


def describe(holder: dict) -> str:
    if not holder:
        return "holder unknown"
    parts = [f"pid {holder.get('pid', '?')} on host {holder.get('host', '?')}", f"since {holder.get('since', '?')}"]
    if holder.get("command"):
        parts.append(f"running {holder['command']!r}")
    return ", ".join(parts)
