"""Reading ``<split>.npz`` archives: plain members, pickled members rebuilt without unpickling, located errors."""

from __future__ import annotations

import fractions
import zipfile

import numpy as np
import pytest
from hostile import WritesMarker

from gns_builtins.datasets._formats.npz_common import NpzSplitsDataset, open_npz, read_array_pickle, read_member
from gns_framework.errors import DatasetError


def object_array(*items) -> np.ndarray:
    array = np.empty(len(items), dtype=object)
    array[:] = list(items)
    return array


def test_a_missing_split_file_is_named(tmp_path):
    with pytest.raises(DatasetError, match=r"train\.npz: split file not found"):
        open_npz(tmp_path / "train.npz")


def test_a_file_that_is_not_an_archive_is_named(tmp_path):
    (tmp_path / "train.npz").write_bytes(b"PK\x03\x04 not really a zip")
    with pytest.raises(DatasetError, match=r"train\.npz: not a readable \.npz archive \(truncated or corrupt\?\)"):
        open_npz(tmp_path / "train.npz")


def test_read_member_returns_plain_arrays_and_refuses_pickled_ones(tmp_path):
    file = tmp_path / "train.npz"
    np.savez(file, plain=np.arange(4.0), pickled=object_array(np.arange(2), np.arange(3)))
    archive = open_npz(file)
    np.testing.assert_array_equal(read_member(archive, file, "plain"), np.arange(4.0))
    with pytest.raises(DatasetError, match=r"train\.npz: pickled: holds a pickled object array.*never unpickles"):
        read_member(archive, file, "pickled")


def test_a_missing_member_is_named(tmp_path):
    file = tmp_path / "train.npz"
    np.savez(file, plain=np.arange(4.0))
    with pytest.raises(DatasetError, match=r"train\.npz: a/position: truncated or corrupt member"):
        read_member(open_npz(file), file, "a/position")


def test_an_object_array_of_arrays_is_rebuilt_without_the_users_grant(tmp_path):
    file = tmp_path / "train.npz"
    positions, types = np.arange(12, dtype=np.float32).reshape(2, 3, 2), np.array([6, 6, 3])
    np.savez(file, simulation_trajectory_0=object_array(positions, types))
    item = read_array_pickle(open_npz(file), file, "simulation_trajectory_0")
    assert item.dtype == object and len(item) == 2
    np.testing.assert_array_equal(item[0], positions)
    assert item[0].dtype == np.float32
    np.testing.assert_array_equal(item[1], types)


def test_a_pickle_naming_code_is_refused_without_running_it_and_the_grant_is_suggested(tmp_path):
    marker = tmp_path / "ran"
    file = tmp_path / "data" / "train.npz"
    file.parent.mkdir()
    np.savez(file, m=object_array(WritesMarker(marker), np.arange(3)))
    with pytest.raises(DatasetError, match=r"train\.npz: m: refused to unpickle builtins\.exec") as info:
        read_array_pickle(open_npz(file), file, "m")
    assert not marker.exists(), "the payload ran"
    # The grant names the folder, not the file (it is given per folder on the command line).
    assert f"--allow-pickle {file.parent} (gns convert" in str(info.value)


def test_with_the_users_grant_numpy_reads_any_pickle(tmp_path):
    file = tmp_path / "train.npz"
    np.savez(file, m=object_array(fractions.Fraction(1, 3), np.arange(3)))
    with pytest.raises(DatasetError, match=r"refused to unpickle fractions\.Fraction"):
        read_array_pickle(open_npz(file), file, "m")
    item = read_array_pickle(open_npz(file, allow_pickle=True), file, "m")
    assert item[0] == fractions.Fraction(1, 3)


def test_a_damaged_pickle_is_named_by_file_and_member(tmp_path):
    file = tmp_path / "train.npz"
    np.savez(file, m=object_array(np.arange(6.0), np.arange(3)))
    with zipfile.ZipFile(file) as archive:
        whole = archive.read("m.npy")
    with zipfile.ZipFile(file, "w") as archive:
        archive.writestr("m.npy", whole[: len(whole) - 20])
    with pytest.raises(
        DatasetError, match=r"train\.npz: m: not a numpy object array of arrays \(truncated or corrupt\?\)"
    ):
        read_array_pickle(open_npz(file), file, "m")


def test_a_split_is_present_when_its_file_is(tmp_path):
    class Layout(NpzSplitsDataset):
        name = "test_layout"

        def split(self, name):
            raise NotImplementedError

    (tmp_path / "valid.npz").write_bytes(b"")
    dataset = Layout(Layout.Params(), tmp_path)
    assert dataset.has_split("valid") and not dataset.has_split("train")
    assert dataset.splits() == ["valid"]
