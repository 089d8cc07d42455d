"""An uncompressed .npz member memory-mapped: the same values numpy reads, and None where it cannot be mapped."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest

from gns_framework.data.npz_mapping import mapped_member
from gns_framework.errors import DatasetError


def _write(path: Path, arrays: dict[str, np.ndarray], compress: bool, allow_pickle: bool = False) -> None:
    with zipfile.ZipFile(path, "w") as archive:
        for name, array in arrays.items():
            info = zipfile.ZipInfo(f"{name}.npy")
            info.compress_type = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
            with archive.open(info, "w") as member:
                np.lib.format.write_array(member, array, allow_pickle=allow_pickle)


def test_a_stored_member_maps_to_the_values_numpy_reads(tmp_path):
    rng = np.random.default_rng(0)
    arrays = {
        "a/position": rng.normal(size=(7, 5, 3)).astype(np.float32),
        "a/particle_type": np.arange(5, dtype=np.int64),
        "b/fortran": np.asfortranarray(rng.normal(size=(4, 6))),
    }
    path = tmp_path / "train.npz"
    _write(path, arrays, compress=False)
    with np.load(path) as archive:
        for name, array in arrays.items():
            mapped = mapped_member(path, archive.zip, name)
            assert isinstance(mapped, np.memmap) and not mapped.flags.writeable
            assert mapped.dtype == array.dtype and mapped.shape == array.shape
            np.testing.assert_array_equal(mapped, array)
            np.testing.assert_array_equal(mapped[2:4], archive[name][2:4])


def test_compressed_object_and_empty_members_are_left_to_numpy(tmp_path):
    path = tmp_path / "train.npz"
    _write(path, {"a/position": np.ones((3, 2, 2), np.float32)}, compress=True)
    with np.load(path) as archive:
        assert mapped_member(path, archive.zip, "a/position") is None
    stored = tmp_path / "stored.npz"
    objects = np.empty(1, dtype=object)
    objects[0] = np.zeros(2)
    _write(stored, {"o": objects, "e": np.zeros((0, 3), np.float32)}, compress=False, allow_pickle=True)
    with np.load(stored) as archive:
        assert mapped_member(stored, archive.zip, "o") is None  # never unpickled here
        assert mapped_member(stored, archive.zip, "e") is None


def test_a_member_shorter_than_its_header_promises_names_the_file_and_member(tmp_path):
    path = tmp_path / "train.npz"
    _write(path, {"a/position": np.ones((8, 4, 2), np.float32)}, compress=False)
    with np.load(path) as archive:
        info = archive.zip.getinfo("a/position.npy")
        # Rewrite the .npy header in place with a larger first dimension (same header length).
        raw = bytearray(path.read_bytes())
        header_at = raw.index(b"(8, 4, 2)", info.header_offset)
        raw[header_at : header_at + 9] = b"(9, 4, 2)"
        path.write_bytes(bytes(raw))
        with pytest.raises(DatasetError, match=r"train\.npz: a/position: the \.npy header promises 288 bytes"):
            mapped_member(path, archive.zip, "a/position")
