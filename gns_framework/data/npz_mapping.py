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
feeds changed values. So a map carries the identity of the file it was made from
(:class:`~.file_identity.FileIdentity`) and checks it whenever a part of it is taken
(every window): a file that changed is a DatasetError naming it and what changed,
never a signal and never changed data.
"""

from __future__ import annotations

import os
import struct
import zipfile
from pathlib import Path

import numpy as np

from ..errors import DatasetError
from .file_identity import FileIdentity

_LOCAL_HEADER = struct.Struct("<4s22xHH")
"""A zip local file header's signature, then (after 22 bytes we do not need) its name and extra field lengths."""
_LOCAL_SIGNATURE = b"PK\x03\x04"


class CheckedMemmap(np.memmap):
    """A read-only map that checks its file is unchanged whenever a part of it is taken (a window, a stride).

    ``identity`` is the file's when it was mapped; slices keep it. Reading a truncated
    map ends the process with SIGBUS, so the check comes before the slice is read.
    """

    identity: FileIdentity | None = None

    def __array_finalize__(self, obj) -> None:
        super().__array_finalize__(obj)
        self.identity = getattr(obj, "identity", None)

    def __getitem__(self, index):
        if self.identity is not None and self.filename is not None:
            self.identity.check(self.filename)
        return super().__getitem__(index)


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
