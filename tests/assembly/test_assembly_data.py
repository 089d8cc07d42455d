"""Opening a recipe's dataset (``gns_framework.assembly.data``): the folder the recipe or the command names, a
missing one as a one-line error, every k-th frame when ``frame_stride`` asks, the pickle grant only for the folder
it names, and the scene derived from the train and valid splits together."""

from __future__ import annotations

import numpy as np
import pytest
from synthetic import soft_sphere_trajectory, synthetic_metadata
from tiny import tiny_recipe

from gns_framework.assembly.data import open_dataset, prepare_data
from gns_framework.config.recipe import DatasetSpec
from gns_framework.data.stride import FrameStrideDataset
from gns_framework.errors import DatasetError


@pytest.fixture(scope="module")
def folder(tmp_path_factory, registry):
    """A dataset of two train trajectories and one test one, 9 frames each, and no valid split."""
    splits = {
        "train": [soft_sphere_trajectory(i, frames=9, block=3, key=f"train_{i}") for i in range(2)],
        "test": [soft_sphere_trajectory(2, frames=9, block=3, key="test_0")],
    }
    path = tmp_path_factory.mktemp("data") / "d"
    registry.get("dataset", "safe").write(path, synthetic_metadata(splits["train"], 2), splits)
    return path


def test_the_recipes_folder_unless_the_command_names_another(folder, registry, tmp_path):
    dataset = open_dataset(DatasetSpec(name="safe", path=str(tmp_path / "elsewhere")), registry, path=folder)
    assert type(dataset) is registry.get("dataset", "safe") and dataset.path == folder
    assert open_dataset(DatasetSpec(name="safe", path=str(folder)), registry).path == folder
    missing = tmp_path / "nope"
    with pytest.raises(DatasetError) as caught:
        open_dataset(DatasetSpec(name="safe", path=str(missing)), registry)
    assert str(caught.value) == f"{missing}: dataset folder not found (dataset.path in the recipe, or --dataset)"


def test_a_frame_stride_shows_every_kth_frame_with_dt_scaled(folder, registry):
    plain = open_dataset(DatasetSpec(name="safe", path=str(folder)), registry)
    strided = open_dataset(DatasetSpec(name="safe", path=str(folder), frame_stride=3), registry)
    assert isinstance(strided, FrameStrideDataset) and strided.stride == 3
    # 9 stored frames seen every 3rd: frames 0, 3 and 6.
    np.testing.assert_array_equal(strided.split("test")[0].position, plain.split("test")[0].position[::3])
    assert strided.metadata().dt == pytest.approx(3 * plain.metadata().dt, rel=1e-12)
    assert strided.metadata().sequence_length == 3


def test_the_pickle_grant_holds_only_for_the_folder_it_names(folder, registry, tmp_path):
    spec = DatasetSpec(name="safe", path=str(folder))
    assert not open_dataset(spec, registry).allow_pickle  # never granted by a recipe
    assert open_dataset(spec, registry, allow_pickle=folder).allow_pickle
    with pytest.raises(DatasetError, match=r"--allow-pickle .*other: this command reads the dataset in "):
        open_dataset(spec, registry, allow_pickle=tmp_path / "other")
    # The strided view keeps the grant of the dataset it shows.
    strided = DatasetSpec(name="safe", path=str(folder), frame_stride=2)
    assert open_dataset(strided, registry, allow_pickle=folder).allow_pickle


def test_the_scene_covers_the_types_of_the_valid_split_too(registry, tmp_path):
    sand = soft_sphere_trajectory(0, frames=8, block=3, particle_types=(6,), key="train_0")
    water = soft_sphere_trajectory(1, frames=8, block=3, particle_types=(5,), key="valid_0")
    registry.get("dataset", "safe").write(
        tmp_path / "d", synthetic_metadata([sand], 2), {"train": [sand], "valid": [water]}
    )
    prepared = prepare_data(tiny_recipe(tmp_path / "d", registry), registry)
    assert [t.key for t in prepared.train] == ["train_0"] and [t.key for t in prepared.valid] == ["valid_0"]
    # A type seen only in validation still gets its embedding row: the model is sized for both.
    assert prepared.setup.particle_types == (5, 6) and prepared.setup.dim == 2
    assert prepared.metadata == prepared.dataset.metadata()


def test_without_a_valid_split_there_is_nothing_to_validate_on(folder, registry):
    prepared = prepare_data(tiny_recipe(folder, registry), registry)
    assert prepared.valid is None and len(prepared.train) == 2
    assert prepared.setup.particle_types == (5,)
    with pytest.warns(DeprecationWarning, match=r"PreparedData\.scene is now \.setup"):
        assert prepared.scene is prepared.setup  # its name until 0.2
