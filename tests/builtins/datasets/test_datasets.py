"""Dataset layouts: round trips, pickled members, clear errors on damaged or inconsistent files."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gns_framework.data.metadata import compute_statistics, load_metadata
from gns_framework.data.trajectory import Trajectory
from gns_framework.errors import DatasetError
from synthetic import soft_sphere_trajectory, synthetic_metadata


@pytest.fixture(scope="module")
def trajectories():
    return [
        soft_sphere_trajectory(0, frames=12, key="a", particle_types=(5, 6), kinematic_floor=True, with_property=True),
        soft_sphere_trajectory(1, frames=12, key="b", particle_types=(5, 6), kinematic_floor=True, with_property=True),
    ]


@pytest.mark.parametrize("layout", ["safe", "npz"])
def test_round_trip(layout, trajectories, tmp_path, registry):
    cls = registry.get("dataset", layout)
    metadata = synthetic_metadata(trajectories, 2)
    cls.write(tmp_path, metadata, {"train": trajectories})
    dataset = cls(cls.Params(), tmp_path)
    assert dataset.metadata() == metadata
    assert dataset.splits() == ["train"]
    loaded = dataset.split("train")
    assert len(loaded) == 2
    for original, back in zip(trajectories, loaded):
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


def test_invalid_metadata_names_file_and_field(tmp_path):
    (tmp_path / "metadata.json").write_text(json.dumps({"bounds": [[0, 1]], "dim": 2}))
    with pytest.raises(DatasetError) as info:
        load_metadata(tmp_path)
    message = str(info.value)
    assert "metadata.json" in message and "sequence_length" in message and "vel_mean" in message


def test_nan_and_shape_errors_name_the_field():
    position = np.zeros((5, 3, 2), np.float32)
    position[2, 1, 0] = np.nan
    with pytest.raises(DatasetError, match="'t0': position: non-finite value at frame 2, particle 1"):
        Trajectory(position, np.zeros(3), key="t0").validated("f.npz")
    with pytest.raises(DatasetError, match="particle_type: expected shape"):
        Trajectory(np.zeros((5, 3, 2), np.float32), np.zeros(4), key="t0").validated("f.npz")


def test_statistics_from_data():
    position = np.zeros((4, 2, 2), np.float32)
    position[:, 0, 0] = [0.0, 1.0, 3.0, 6.0]
    stats = compute_statistics([Trajectory(position, np.array([5, 3]))], kinematic_types=[3])
    assert stats["vel_mean"] == [2.0, 0.0]
    assert stats["acc_mean"] == [1.0, 0.0]
    assert stats["acc_std"] == [0.0, 0.0]
