"""Outputs are never silently replaced (issue 30, item 4).

Each command that writes a folder (``gns convert``, ``generate``, ``rollout``,
``evaluate``, ``render --vtk``) records itself in ``<folder>/.gns-output.json``. A
non-empty folder is written into only when it is that command's own earlier
result, which is then replaced (and said so), or with ``--overwrite``; anything
else is refused, naming what the folder holds. A file output (``gns render --gif``)
that exists is replaced only with ``--overwrite``.

A dataset (convert, generate) is written whole into a temporary sibling folder and
renamed into place, the earlier folder moved aside first and deleted after: a reader
sees the old dataset, then the new one, never a mix of the two, and a failed run
leaves the old one as it was.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import sys
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path

from .data.atomic import fsync_directory, process_umask
from .errors import GnsError
from .io.owned_files import LinkRefused, describe_link, write_owned_text

MARKER = ".gns-output.json"
"""File recording which command wrote the folder it is in."""


def recorded_command(folder: Path) -> str | None:
    """The command ``folder``'s marker names, None when it has none (or an unreadable one)."""
    try:
        with open(Path(folder) / MARKER, "rb") as handle:
            recorded = json.loads(handle.read(4096).decode("utf-8"))
    except (OSError, ValueError, UnicodeDecodeError):
        return None
    command = recorded.get("command") if isinstance(recorded, dict) else None
    return command if isinstance(command, str) else None


def describe_contents(folder: Path, most: int = 5) -> str:
    """What ``folder`` holds, in a few words: its first entries and how many more."""
    names = sorted(p.name + ("/" if p.is_dir() else "") for p in folder.iterdir() if p.name != MARKER)
    shown = ", ".join(names[:most]) + (f" and {len(names) - most} more" if len(names) > most else "")
    other = recorded_command(folder)
    written = f" (written by gns {other})" if other else ""
    return f"{len(names)} entr{'y' if len(names) == 1 else 'ies'}{written}: {shown}"


def check_folder(folder: str | Path, command: str, overwrite: bool, own: Callable[[Path], bool] | None = None) -> bool:
    """Refuse ``folder`` unless it is absent, empty, ``gns command``'s own earlier result, or ``overwrite`` is given.

    ``own``: recognises an earlier result written before markers existed. Returns
    whether something already there will be replaced.
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise GnsError(f"{folder}: is a file, not a folder: gns {command} writes a folder there; choose another --out")
    if not folder.is_dir() or not any(p.name != MARKER for p in folder.iterdir()):
        return False
    if overwrite or recorded_command(folder) == command or (own is not None and own(folder)):
        return True
    raise GnsError(
        f"{folder}: not empty and not an earlier result of gns {command}: it holds {describe_contents(folder)}; "
        f"choose another folder, or pass --overwrite to write over it"
    )


def claim_folder(folder: str | Path, command: str, overwrite: bool, own: Callable[[Path], bool] | None = None) -> Path:
    """:func:`check_folder`, then create ``folder`` and mark it as ``gns command``'s; says when it replaces
    something."""
    folder = Path(folder)
    if check_folder(folder, command, overwrite, own):
        refuse_links_inside(folder, command)
        print(f"gns {command}: writing over the earlier contents of {folder}", file=sys.stderr)
    folder.mkdir(parents=True, exist_ok=True)
    write_marker(folder, command)
    return folder


def refuse_links_inside(folder: Path, command: str) -> None:
    """Refuse a folder about to be written over when anything inside it is a symbolic link.

    A folder copied from elsewhere may hold ``report.md -> ~/notes.md``: the writers
    (matplotlib, meshio, csv) would follow it out of the folder. Links are found by a
    walk that never follows them; the first is named.
    """
    for root, directories, files in os.walk(folder, followlinks=False):
        for name in sorted(directories + files):
            path = Path(root) / name
            if path.is_symlink():
                raise LinkRefused(
                    f"{path}: is {describe_link(path)}; gns {command} never writes through a link in a folder it "
                    "owns (remove the link, or choose another folder)"
                )


def write_marker(folder: Path, command: str) -> None:
    write_owned_text(Path(folder) / MARKER, json.dumps({"command": command}) + "\n", "output folder's marker")


def check_file(path: str | Path, command: str, overwrite: bool, option: str) -> None:
    """Refuse an existing file output ``path`` unless ``overwrite``."""
    path = Path(path)
    if path.is_dir():
        raise GnsError(f"{path}: {option}: is a folder, not a file")
    if path.exists() and not overwrite:
        raise GnsError(
            f"{path}: {option}: the file exists ({path.stat().st_size} bytes); gns {command} does not replace it "
            "unless you pass --overwrite"
        )


@contextlib.contextmanager
def replaced_whole(folder: str | Path, command: str) -> Iterator[Path]:
    """Yield an empty temporary sibling of ``folder`` to write into; on success it replaces ``folder`` whole.

    The earlier folder (if any) is renamed aside, the new one renamed into its place,
    and the earlier one then deleted: at no moment does ``folder`` hold a mix of both.
    On failure the temporary folder is removed and ``folder`` is left as it was.
    """
    folder = Path(folder)
    target = folder.resolve() if folder.is_symlink() else folder
    parent = target.parent
    parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".tmp", dir=parent))
    os.chmod(tmp, 0o777 & ~process_umask())  # mkdtemp makes it 0700; the dataset folder follows the umask
    try:
        yield tmp
        write_marker(tmp, command)
        old = None
        if target.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".old", dir=parent))
            os.rename(target, old / target.name)
        os.rename(tmp, target)
        fsync_directory(parent)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
