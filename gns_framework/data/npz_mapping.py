"""An uncompressed member of an ``.npz`` archive memory-mapped: its values are read from disk when they are used.

An ``.npz`` is a zip archive of ``.npy`` files. A member stored without compression
(``ZIP_STORED``) is the ``.npy`` bytes as they are, at a fixed place in the archive:
after the member's local zip header comes the ``.npy`` header (magic, version, the
dtype, shape and order), then the array's raw bytes. Mapping those bytes gives an
array whose pages the operating system reads when a slice is used, so a training
process that takes a window of 8 frames from a trajectory of 240 reads those 8
frames, and holds no more of the dataset than the windows it trains on.

Only plain arrays are mapped: an object (pickled) member is never mapped nor read here.

A mapped file that is truncated under its reader makes the kernel end the reader with
SIGBUS at the first page past the new end, with no message; one rewritten in place
feeds changed values. So a mapping carries the identity of the file it was made from
(device, inode, size, modification time), and :func:`read_frames` (every window read)
and the split's loads check it before reading: a file that changed is a DatasetError
naming it and what changed, never a signal and never changed data.
"""

from __future__ import annotations

import os
import struct
import zipfile
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ..errors import DatasetError

_LOCAL_HEADER = struct.Struct("<4s22xHH")
"""A zip local file header's signature, then (after 22 bytes we do not need) its name and extra field lengths."""
_LOCAL_SIGNATURE = b"PK\x03\x04"


class FileIdentity(NamedTuple):
    """What tells a file apart from a changed one: its device and inode, size and modification time (ns)."""

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

    def change(self, now: FileIdentity | None) -> str | None:
        """How ``now`` differs from this identity, in words; None when it is the same file, unchanged."""
        if now is None:
            return "it is gone"
        if (now.device, now.inode) != (self.device, self.inode):
            return "another file replaced it"
        if now.size != self.size:
            return f"its size went from {self.size} to {now.size} bytes (truncated?)" if now.size < self.size else (
                f"its size went from {self.size} to {now.size} bytes"
            )
        if now.modified_ns != self.modified_ns:
            return "it was rewritten (modification time changed)"
        return None


class DatasetChanged(DatasetError):
    """A data file changed under its reader (truncated, rewritten or replaced)."""


class CheckedMemmap(np.memmap):
    """A read-only map of a file that remembers the file's identity when it was mapped (slices keep it)."""

    identity: FileIdentity | None = None

    def __array_finalize__(self, obj) -> None:
        super().__array_finalize__(obj)
        self.identity = getattr(obj, "identity", None)


def check_unchanged(array, what: str = "") -> None:
    """Raise DatasetError when ``array`` maps a file that changed since it was mapped; nothing for other arrays.

    Called before the values of a map are read: reading a truncated map ends the process with SIGBUS.
    """
    mapping = array
    while mapping is not None and not isinstance(mapping, CheckedMemmap):
        mapping = getattr(mapping, "base", None)  # a view of a map (np.asarray of a memmap is a plain view of it)
    if mapping is None or mapping.identity is None:
        return
    filename = mapping.filename
    change = mapping.identity.change(FileIdentity.of_path(filename) if filename else None)
    if change is not None:
        raise DatasetChanged(
            f"{filename}: changed while it was being read{what} ({change}); stopped rather than read it: put the data "
            "back as it was (or train on a copy), then resume"
        )


def read_frames(frames) -> np.ndarray:
    """A copy of ``frames`` (e.g. a window's slice of a trajectory's positions), checked unchanged before and after.

    Shapes: whatever ``frames`` holds (e.g. (W, N, d)).
    """
    check_unchanged(frames)
    copied = np.array(frames)
    check_unchanged(frames)  # rewritten while it was copied: the copy may mix old and new values
    return copied


def mapped_member(path: Path, archive: zipfile.ZipFile, key: str) -> CheckedMemmap | None:
    """Member ``key`` of the ``.npz`` at ``path`` mapped read-only, or None where it cannot be mapped.

    None for a compressed member, an object (pickled) dtype, or an empty array; the
    caller reads those as numpy does. A member whose header or size does not add up
    is a DatasetError naming the file and the member.

    Shapes: whatever the member holds (e.g. position (T, N, d) float32).
    """
    info = archive.getinfo(f"{key}.npy")
    if info.compress_type != zipfile.ZIP_STORED:
        return None
    where = f"{path}: {key}"
    with open(path, "rb") as file:
        file.seek(info.header_offset)
        local = file.read(_LOCAL_HEADER.size)
        if len(local) < _LOCAL_HEADER.size:
            raise DatasetError(f"{where}: truncated zip header")
        signature, name_length, extra_length = _LOCAL_HEADER.unpack(local)
        if signature != _LOCAL_SIGNATURE:
            raise DatasetError(f"{where}: not a zip member header at byte {info.header_offset} (corrupt archive?)")
        start = info.header_offset + _LOCAL_HEADER.size + name_length + extra_length
        file.seek(start)
        try:
            version = np.lib.format.read_magic(file)
            read_header = {
                (1, 0): np.lib.format.read_array_header_1_0,
                (2, 0): np.lib.format.read_array_header_2_0,
            }.get(version)
            if read_header is None:
                raise ValueError(f"unsupported .npy format version {version}")
            shape, fortran_order, dtype = read_header(file)
        except ValueError as exc:
            raise DatasetError(f"{where}: unreadable .npy header: {exc}") from None
        offset = file.tell()
        identity = FileIdentity.of(os.fstat(file.fileno()))
    if dtype.hasobject or 0 in shape:
        return None
    size = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    if offset - start + size != info.file_size:
        raise DatasetError(
            f"{where}: the .npy header promises {size} bytes of {dtype} {shape}, but the member holds "
            f"{info.file_size - (offset - start)} (truncated or corrupt?)"
        )
    if offset + size > identity.size:
        raise DatasetError(f"{where}: the member runs past the end of the file ({identity.size} bytes; truncated?)")
    mapped = CheckedMemmap(path, dtype=dtype, mode="r", offset=offset, shape=shape, order="F" if fortran_order else "C")
    mapped.identity = identity
    return mapped
