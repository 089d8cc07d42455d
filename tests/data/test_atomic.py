"""Atomic writes: the file's data, then the rename, then the directory's entry reach the disk, in that order."""

from __future__ import annotations

import os
import stat

from gns_framework.data.atomic import write_text_atomic


def test_the_rename_is_followed_by_an_fsync_of_the_directory(tmp_path, monkeypatch):
    """Without the directory's fsync a power loss can undo the rename of a file reported as written."""
    events = []
    fsync, replace = os.fsync, os.replace

    def recording_fsync(fd):
        mode = os.fstat(fd).st_mode
        events.append(
            ("fsync directory", os.readlink(f"/proc/self/fd/{fd}")) if stat.S_ISDIR(mode) else ("fsync file",)
        )
        fsync(fd)

    def recording_replace(source, target):
        events.append(("rename", str(target)))
        replace(source, target)

    monkeypatch.setattr(os, "fsync", recording_fsync)
    monkeypatch.setattr(os, "replace", recording_replace)
    path = tmp_path / "folder" / "metadata.json"
    write_text_atomic(path, "{}\n")
    assert events == [("fsync file",), ("rename", str(path)), ("fsync directory", str(path.parent))]
    assert path.read_text() == "{}\n"
