"""The dataset-layout contract: metadata and split are required; splits, has_split, split files, write and
__init__ defaults."""

from __future__ import annotations

from pathlib import Path

import pytest

from gns_framework.contracts import Dataset, Params
from gns_framework.errors import DatasetError


def test_a_layout_without_metadata_or_split_cannot_be_built(tmp_path):
    class NoSplit(Dataset):
        name = "no_split"

        def metadata(self):
            return None

    class NoMetadata(Dataset):
        name = "no_metadata"

        def split(self, name):
            return []

    with pytest.raises(TypeError, match="abstract method split"):
        NoSplit(Params(), tmp_path)
    with pytest.raises(TypeError, match="abstract method metadata"):
        NoMetadata(Params(), tmp_path)


class Listed(Dataset):
    """A layout whose splits are the names in ``present``."""

    name = "listed"
    present: tuple[str, ...] = ()

    def metadata(self):
        return None

    def split(self, name):
        return []

    def has_split(self, name):
        return name in self.present


def test_the_path_becomes_a_path_and_pickles_stay_refused_unless_granted(tmp_path):
    dataset = Listed(Params(), str(tmp_path))
    assert dataset.path == tmp_path and isinstance(dataset.path, Path)
    assert dataset.params == Params() and dataset.allow_pickle is False
    assert Listed(Params(), tmp_path, allow_pickle=True).allow_pickle is True


def test_splits_lists_those_on_disk_in_train_valid_test_order(tmp_path):
    dataset = Listed(Params(), tmp_path)
    dataset.present = ("test", "other", "train")
    assert dataset.splits() == ["train", "test"]  # "other" is no split name


def test_a_layout_that_does_not_say_has_no_split(tmp_path):
    class Silent(Dataset):
        name = "silent"

        def metadata(self):
            return None

        def split(self, name):
            return []

    assert Silent(Params(), tmp_path).splits() == []


def test_a_layout_of_one_file_per_split_finds_its_files_and_names_a_missing_one(tmp_path):
    class PerFile(Dataset):
        name = "per_file"
        split_suffix = ".h5"

        def metadata(self):
            return None

        def split(self, name):
            return [self.split_file(name)]

    (tmp_path / "valid.h5").write_bytes(b"")
    (tmp_path / "train.npz").write_bytes(b"")  # another layout's ending
    dataset = PerFile(Params(), tmp_path)
    assert dataset.splits() == ["valid"]
    assert dataset.split("valid") == [tmp_path / "valid.h5"]
    with pytest.raises(DatasetError, match=r"train\.h5: split file not found"):
        dataset.split("train")
    with pytest.raises(TypeError, match="'listed' does not keep one file per split"):
        Listed(Params(), tmp_path).split_file("train")


def test_a_layout_is_read_only_unless_it_writes(tmp_path):
    assert Listed.writable is False
    with pytest.raises(NotImplementedError, match="dataset layout 'listed' is read-only"):
        Listed.write(tmp_path, None, {})
