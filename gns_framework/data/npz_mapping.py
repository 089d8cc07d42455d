"""An uncompressed member of an ``.npz`` archive memory-mapped: its values are read from disk when they are used.

An ``.npz`` is a zip archive of ``.npy`` files. A member stored without compression
(``ZIP_STORED``) is the ``.npy`` bytes as they are, at a fixed place in the archive:
after the member's local zip header comes the ``.npy`` header (magic, version, the
dtype, shape and order), then the array's raw bytes. Mapping those bytes gives an
array whose pages the operating system reads when a slice is used, so a training
process that takes a window of 8 frames from a trajectory of 240 reads those 8
frames, and holds no more of the dataset than the windows it trains on.

Only plain arrays are mapped: an object (pickled) member is never mapped nor read here.
"""

from __future__ import annotations

import struct
import zipfile
from pathlib import Path

import numpy as np

from ..errors import DatasetError

_LOCAL_HEADER = struct.Struct("<4s22xHH")
"""A zip local file header's signature, then (after 22 bytes we do not need) its name and extra field lengths."""
_LOCAL_SIGNATURE = b"PK\x03\x04"


def mapped_member(path: Path, archive: zipfile.ZipFile, key: str) -> np.memmap | None:
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
    if dtype.hasobject or 0 in shape:
        return None
    size = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    if offset - start + size != info.file_size:
        raise DatasetError(
            f"{where}: the .npy header promises {size} bytes of {dtype} {shape}, but the member holds "
            f"{info.file_size - (offset - start)} (truncated or corrupt?)"
        )
    return np.memmap(path, dtype=dtype, mode="r", offset=offset, shape=shape, order="F" if fortran_order else "C")
