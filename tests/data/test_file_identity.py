"""A data file's identity (data/file_identity.py): a truncated, rewritten, replaced or removed file is named with
what changed, and reads between two checks see the same file."""

from __future__ import annotations

import os
import re

import pytest

from gns_framework.data.file_identity import DatasetChanged, FileIdentity, unchanged_reads
from gns_framework.errors import DatasetError


@pytest.fixture
def data_file(tmp_path):
    path = tmp_path / "train.npz"
    path.write_bytes(b"x" * 100)
    return path


def test_an_unchanged_file_passes_and_a_missing_one_has_no_identity(data_file, tmp_path):
    FileIdentity.of_path(data_file).check(data_file)
    assert FileIdentity.of_path(tmp_path / "nothing") is None


@pytest.mark.parametrize(
    "change, said",
    [
        (lambda p: p.write_bytes(b"x" * 10), "size went from 100 to 10 bytes (truncated?)"),
        (lambda p: p.write_bytes(b"x" * 200), "size went from 100 to 200 bytes"),
        (lambda p: os.utime(p, ns=(1, 1)), "rewritten (modification time changed)"),
        (lambda p: p.unlink(), "it is gone"),
    ],
)
def test_each_change_is_named_with_the_file(data_file, change, said):
    identity = FileIdentity.of_path(data_file)
    change(data_file)
    with pytest.raises(
        DatasetChanged, match=rf"{re.escape(str(data_file))}: changed while it was being read \(.*{re.escape(said)}"
    ) as raised:
        identity.check(data_file)
    assert isinstance(raised.value, DatasetError) and "resume" in str(raised.value)


def test_a_replaced_file_is_another_file(data_file):
    identity = FileIdentity.of_path(data_file)
    replacement = data_file.with_name("new.npz")
    replacement.write_bytes(b"x" * 100)
    stat = os.stat(data_file)
    os.utime(replacement, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    os.replace(replacement, data_file)  # same size and time, another inode
    with pytest.raises(DatasetChanged, match="another file replaced it"):
        identity.check(data_file)


def test_unchanged_reads_check_before_and_after_each_read(data_file):
    calls = []
    read = unchanged_reads(lambda key: calls.append(key) or key, data_file)
    assert read("a") == "a"

    def rewriting(key):
        data_file.write_bytes(b"y" * 50)  # rewritten during the read: its values may mix old and new
        return key

    with pytest.raises(DatasetChanged, match="size went from 100 to 50"):
        unchanged_reads(rewriting, data_file)("b")
    with pytest.raises(DatasetChanged):
        read("c")  # and before the next one
    assert calls == ["a"]


def test_a_source_that_is_no_file_is_read_unchecked(tmp_path):
    read = lambda key: key  # noqa: E731
    assert unchanged_reads(read, tmp_path / "in-memory") is read
