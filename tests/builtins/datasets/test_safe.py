"""The safe layout: every field round-trips, file order is kept, and nothing is ever unpickled."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from synthetic import synthetic_metadata

from gns_builtins.datasets.safe import SafeDataset
from gns_framework.errors import DatasetError


def test_round_trip(trajectories, tmp_path, registry):
    cls = registry.get("dataset", "safe")
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


def test_the_safe_layout_never_unpickles(trajectories, tmp_path, registry):
    """A pickled member in a safe file is refused, with no opt-in to suggest: the layout has none."""
    cls = registry.get("dataset", "safe")
    cls.write(tmp_path, synthetic_metadata(trajectories, 2), {"train": trajectories})
    with np.load(tmp_path / "train.npz") as archive:
        members = dict(archive)
    members["a/position"] = np.array([members["a/position"]], dtype=object)
    np.savez(tmp_path / "train.npz", **members)
    with pytest.raises(DatasetError, match=r"train\.npz: a/position: holds a pickled object array") as info:
        cls(cls.Params(), tmp_path).split("train")[0]
    assert "allow" not in str(info.value)


def test_truncated_split_file_is_a_clear_error(trajectories, tmp_path, registry):
    cls = registry.get("dataset", "safe")
    cls.write(tmp_path, synthetic_metadata(trajectories, 2), {"train": trajectories})
    data = (tmp_path / "train.npz").read_bytes()
    (tmp_path / "train.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(DatasetError, match=r"train\.npz.*truncated or corrupt"):
        cls(cls.Params(), tmp_path).split("train")[0]


def test_dimension_disagreeing_with_metadata(trajectories, tmp_path, registry):
    cls = registry.get("dataset", "safe")
    metadata = synthetic_metadata(trajectories, 2)
    cls.write(tmp_path, metadata, {"train": trajectories})
    raw = json.loads((tmp_path / "metadata.json").read_text())
    raw.update(
        dim=3,
        bounds=raw["bounds"] + [[0, 1]],
        vel_mean=[0, 0, 0],
        vel_std=[1, 1, 1],
        acc_mean=[0, 0, 0],
        acc_std=[1, 1, 1],
    )
    (tmp_path / "metadata.json").write_text(json.dumps(raw))
    with pytest.raises(DatasetError, match="trajectory 'a': position: has d = 2 but metadata says dim = 3"):
        cls(cls.Params(), tmp_path).split("train")[0]


def test_step_context_bounds_and_walls_round_trip_and_file_order_is_kept(trajectories, tmp_path):
    frames = trajectories[0].num_steps
    # Keys in reverse alphabetical order: the split must keep the order they were written in (seed order).
    rich = replace(
        trajectories[0],
        key="z",
        step_context=np.linspace(0, 1, 2 * frames, dtype=np.float32).reshape(frames, 2),
        bounds=np.array([[0.0, 1.0], [0.1, 0.8]], np.float32),
        walls=np.array([[0.3, 0], [0.3, 0], [0.0, 1], [0.5, 0]], np.float32),
    )
    plain = replace(trajectories[1], key="m", material_property=None)
    SafeDataset.write(tmp_path, synthetic_metadata(trajectories, 2), {"valid": [rich, plain]})
    split = SafeDataset(SafeDataset.Params(), tmp_path).split("valid")
    assert [t.key for t in split] == ["z", "m"]
    for field in ("position", "particle_type", "material_property", "step_context", "bounds", "walls"):
        np.testing.assert_array_equal(getattr(split[0], field), getattr(rich, field), err_msg=field)
    assert split[1].material_property is None and split[1].step_context is None and split[1].walls is None
    assert split[0].position.dtype == np.float32 and split[0].particle_type.dtype == np.int64


def test_trajectories_without_a_key_are_numbered_in_order(trajectories, tmp_path):
    unnamed = [replace(t, key="") for t in trajectories]
    SafeDataset.write(tmp_path, synthetic_metadata(trajectories, 2), {"train": unnamed})
    with np.load(tmp_path / "train.npz") as archive:
        assert sorted(archive.files)[0] == "trajectory_00000/material_property"
    assert [t.key for t in SafeDataset(SafeDataset.Params(), tmp_path).split("train")] == [
        "trajectory_00000",
        "trajectory_00001",
    ]


def test_a_member_that_is_not_a_trajectory_field_is_named(trajectories, tmp_path):
    SafeDataset.write(tmp_path, synthetic_metadata(trajectories, 2), {"train": trajectories[:1]})
    with np.load(tmp_path / "train.npz") as archive:
        members = dict(archive)
    members["a/velocity"] = members["a/position"]
    np.savez(tmp_path / "train.npz", **members)
    with pytest.raises(DatasetError, match=r"train\.npz: member 'a/velocity': expected '<trajectory>/<field>'"):
        SafeDataset(SafeDataset.Params(), tmp_path).split("train")


def test_a_trajectory_without_particle_types_is_named(trajectories, tmp_path):
    SafeDataset.write(tmp_path, synthetic_metadata(trajectories, 2), {"train": trajectories[:1]})
    with np.load(tmp_path / "train.npz") as archive:
        members = {k: v for k, v in archive.items() if k != "a/particle_type"}
    np.savez(tmp_path / "train.npz", **members)
    with pytest.raises(DatasetError, match=r"train\.npz: trajectory 'a': particle_type: missing"):
        SafeDataset(SafeDataset.Params(), tmp_path).split("train")


def test_splits_are_the_files_present(trajectories, tmp_path):
    SafeDataset.write(tmp_path, synthetic_metadata(trajectories, 2), {"test": trajectories[:1], "train": trajectories})
    dataset = SafeDataset(SafeDataset.Params(), tmp_path)
    # In train, valid, test order whatever order they were written in.
    assert dataset.splits() == ["train", "test"]
    with pytest.raises(DatasetError, match=r"valid\.npz: split file not found"):
        dataset.split("valid")
