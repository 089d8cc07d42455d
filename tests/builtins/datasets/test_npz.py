"""The geoelements layout: tuples of arrays read without unpickling, DeepMind's step count, what it cannot hold."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from layout_fixtures import FIXTURES, FLOAT32, expected_position, read
from synthetic import synthetic_metadata

from gns_builtins.datasets.npz import GeoelementsNpzDataset
from gns_framework.errors import DatasetError


def test_round_trip(trajectories, tmp_path, registry):
    cls = registry.get("dataset", "npz")
    metadata = synthetic_metadata(trajectories, 2)
    cls.write(tmp_path, metadata, {"train": trajectories})
    dataset = cls(cls.Params(), tmp_path)
    assert dataset.metadata() == metadata
    assert dataset.splits() == ["train"]
    loaded = dataset.split("train")
    assert len(loaded) == 2
    for original, back in zip(trajectories, loaded, strict=True):
        np.testing.assert_array_equal(original.position, back.position)
        np.testing.assert_array_equal(original.particle_type, back.particle_type)
        np.testing.assert_array_equal(original.material_property, back.material_property)


def test_geoelements_npz_is_read_as_numpy_saved_it(registry):
    metadata, splits = read(registry, "npz", FIXTURES / "geoelements")
    # geoelements' metadata is DeepMind's: sequence_length 3 counts steps, 4 frames.
    assert metadata.sequence_length == 4 and metadata.dim == 2 and list(splits) == ["train", "test"]
    first, second = splits["train"]
    assert (first.key, second.key) == ("simulation_trajectory_0", "simulation_trajectory_1")
    np.testing.assert_array_equal(first.particle_type, [6, 6, 3])
    np.testing.assert_array_equal(second.particle_type, [6, 3])
    assert first.material_property is None
    np.testing.assert_allclose(second.material_property, [[0.6], [0.0]], rtol=FLOAT32)
    np.testing.assert_allclose(second.position, expected_position(4, 2, 1), rtol=FLOAT32)
    np.testing.assert_allclose(splits["test"][0].position, expected_position(4, 2, 0), rtol=FLOAT32)


def test_the_file_counts_steps_where_the_metadata_counts_frames(trajectories, tmp_path):
    metadata = synthetic_metadata(trajectories, 2)
    GeoelementsNpzDataset.write(tmp_path, metadata, {"train": trajectories})
    # 12 frames are 11 steps in geoelements' (DeepMind's) metadata.json, and 12 frames again when read.
    assert json.loads((tmp_path / "metadata.json").read_text())["sequence_length"] == 11
    assert GeoelementsNpzDataset(GeoelementsNpzDataset.Params(), tmp_path).metadata().sequence_length == 12


def test_members_are_geoelements_tuples_with_one_property_stored_flat(trajectories, tmp_path):
    two_properties = replace(
        trajectories[1], material_property=np.stack([np.arange(trajectories[1].num_particles)] * 2, 1)
    )
    unnamed = replace(trajectories[0], key="")
    GeoelementsNpzDataset.write(tmp_path, synthetic_metadata(trajectories, 2), {"train": [unnamed, two_properties]})
    with np.load(tmp_path / "train.npz", allow_pickle=True) as archive:
        assert archive.files == ["simulation_trajectory_0", "b"]
        first, second = archive["simulation_trajectory_0"], archive["b"]
    # (positions, particle_type, material_property): one property per particle as geoelements stores it, (N,).
    assert len(first) == 3 and first[2].shape == (unnamed.num_particles,)
    assert second[2].shape == (two_properties.num_particles, 2)
    back = GeoelementsNpzDataset(GeoelementsNpzDataset.Params(), tmp_path).split("train")
    np.testing.assert_array_equal(back[0].material_property, unnamed.material_property)
    np.testing.assert_array_equal(back[1].material_property, two_properties.material_property)


def test_a_step_context_cannot_be_written(trajectories, tmp_path):
    frames = trajectories[0].num_steps
    with_context = replace(trajectories[0], step_context=np.zeros((frames, 1), np.float32))
    with pytest.raises(DatasetError, match=r"train\.npz: a: the geoelements layout has no step_context"):
        GeoelementsNpzDataset.write(tmp_path, synthetic_metadata(trajectories, 2), {"train": [with_context]})
    assert not (tmp_path / "train.npz").exists()


def test_a_member_that_is_not_a_trajectory_tuple_is_named(trajectories, tmp_path):
    GeoelementsNpzDataset.write(tmp_path, synthetic_metadata(trajectories, 2), {"train": trajectories[:1]})
    np.savez(tmp_path / "train.npz", simulation_trajectory_0=np.zeros(3))
    with pytest.raises(
        DatasetError,
        match=r"train\.npz: trajectory 'simulation_trajectory_0': expected a \(positions, particle_type"
        r"\[, material_property\]\) tuple, got an array of dtype float64 and shape \(3,\)",
    ):
        GeoelementsNpzDataset(GeoelementsNpzDataset.Params(), tmp_path).split("train")[0]
