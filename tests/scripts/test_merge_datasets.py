"""scripts/merge_datasets.py: splits joined with their sources named, statistics over the joined train split."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from load_script import load_script
from synthetic import write_synthetic_dataset

from gns_framework.assembly.data import open_dataset
from gns_framework.config.recipe import DatasetSpec
from gns_framework.data.metadata import compute_statistics, load_metadata
from gns_framework.errors import DatasetError
from gns_framework.plugins import load_registry

ROOT = Path(__file__).resolve().parents[2]
merge_datasets = load_script("scripts/merge_datasets.py")


def trajectories(path: Path, split: str):
    return list(open_dataset(DatasetSpec(name="safe", path=str(path)), load_registry()).split(split))


def test_two_datasets_join_with_their_sources_named_and_statistics_recomputed(tmp_path):
    first = write_synthetic_dataset(tmp_path / "first", train=2, valid=2, test=1)
    second = write_synthetic_dataset(tmp_path / "second", train=3, valid=2, test=1, block=4)
    out = tmp_path / "merged"
    counts = merge_datasets.merge([first, second], out, valid_each=1, test_each=None)
    assert counts == {"train": 5, "valid": 2, "test": 2}
    train = trajectories(out, "train")
    assert [t.key.split("_")[0] for t in train] == ["part0"] * 2 + ["part1"] * 3
    np.testing.assert_array_equal(train[2].position, trajectories(second, "train")[0].position)
    metadata = load_metadata(out)
    expected = compute_statistics(
        trajectories(first, "train") + trajectories(second, "train"), load_registry().kinematic_types()
    )
    np.testing.assert_allclose(metadata.vel_std, expected["vel_std"], rtol=1e-6)
    assert metadata.vel_std != load_metadata(first).vel_std, "the statistics are the joined data's, not the first's"
    sources = json.loads((out / "metadata.json").read_text())["merged_from"]
    assert [s["path"] for s in sources] == [str(first), str(second)]


def test_datasets_of_other_bounds_are_refused_and_nothing_is_written(tmp_path):
    first = write_synthetic_dataset(tmp_path / "first", train=1, valid=0, test=0)
    second = write_synthetic_dataset(tmp_path / "second", train=1, valid=0, test=0)
    raw = json.loads((second / "metadata.json").read_text())
    raw["bounds"] = [[0.0, 2.0], [0.0, 1.0]]
    (second / "metadata.json").write_text(json.dumps(raw))
    with pytest.raises(DatasetError, match="bounds"):
        merge_datasets.merge([first, second], tmp_path / "merged", None, None)
    assert not (tmp_path / "merged").exists()


def test_an_existing_output_folder_is_refused(tmp_path):
    first = write_synthetic_dataset(tmp_path / "first", train=1, valid=0, test=0)
    (tmp_path / "merged").mkdir()
    with pytest.raises(DatasetError, match="exists"):
        merge_datasets.merge([first, first], tmp_path / "merged", None, None)
