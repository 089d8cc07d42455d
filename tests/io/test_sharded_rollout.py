"""A rollout written in shards, one per process (``gns_framework.io.sharded_rollout``): read back as one rollout,
and every way a shard or the manifest can be wrong is an error naming the file and the field."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

from gns_framework.data.metadata import DatasetMetadata
from gns_framework.data.trajectory import Trajectory
from gns_framework.errors import DatasetError
from gns_framework.io.rollout_file import load_rollout
from gns_framework.io.sharded_rollout import (
    MANIFEST,
    RolloutShard,
    is_sharded_rollout,
    load_sharded_rollout,
    write_manifest,
)
from gns_framework.model.rollout_guard import GuardViolation

PARTICLES, HISTORY, STEPS, DIM = 7, 2, 3, 2


def _scene() -> tuple[Trajectory, np.ndarray, DatasetMetadata]:
    """A trajectory of 2 + 3 frames, a prediction of its last 3, and its metadata."""
    rng = np.random.default_rng(0)
    position = rng.uniform(0.1, 0.9, (HISTORY + STEPS, PARTICLES, DIM)).astype(np.float32)
    types = np.array([5, 5, 6, 6, 3, 5, 6])
    friction = rng.uniform(0.3, 0.8, (PARTICLES, 1)).astype(np.float32)
    walls = np.zeros((2 * DIM, 2), dtype=np.float32)
    trajectory = Trajectory(position, types, friction, key="scene", bounds=np.array([[0, 1], [0, 1]]), walls=walls)
    predicted = position[HISTORY:] + np.float32(0.01)
    metadata = DatasetMetadata(
        bounds=[(0.0, 1.0)] * DIM,
        sequence_length=HISTORY + STEPS,
        default_connectivity_radius=0.1,
        dim=DIM,
        dt=0.01,
        vel_mean=[0.0] * DIM,
        vel_std=[1.0] * DIM,
        acc_mean=[0.0] * DIM,
        acc_std=[1.0] * DIM,
    )
    return trajectory, predicted, metadata


def _write(folder, owners: list[list[np.ndarray]], violations=None) -> None:
    """Shards of the scene, process r owning ``owners[r][s]`` at step s (``owners[r][0]`` also at the start)."""
    trajectory, predicted, metadata = _scene()
    for rank, owned in enumerate(owners):
        shard = RolloutShard(folder, rank)
        start = owned[0]
        shard.start(
            start,
            trajectory.position[:HISTORY, start],
            trajectory.particle_type[start],
            trajectory.material_property[start],
            trajectory.particle_type[start] != 3,
        )
        for step in range(STEPS):
            ids = owned[step]
            shard.frame(ids, predicted[step, ids], trajectory.position[HISTORY + step, ids])
        shard.finish([] if violations is None else violations[rank])
    write_manifest(folder, trajectory, STEPS, HISTORY, len(owners), metadata)


# Particles 2 and 5 change process after step 0; process 1 owns none at step 2.
OWNERS = [
    [np.array([0, 1, 2]), np.array([0, 1, 5]), np.array([0, 1, 2, 3, 4, 5, 6])],
    [np.array([3, 4, 5, 6]), np.array([2, 3, 4, 6]), np.array([], dtype=np.int64)],
]


def test_shards_read_back_as_the_whole_rollout(tmp_path):
    folder = tmp_path / "test_0000.rollout"
    clamped = [
        [GuardViolation(1, 3, np.array([1]), "left (farthest: particle 1, 0.2 beyond a wall)", True, 0.2)],
        [
            GuardViolation(1, 3, np.array([6, 3]), "left (farthest: particle 6, 0.3 beyond a wall)", True, 0.3),
            GuardViolation(0, 2, np.array([4]), "have non-finite positions (NaN or Inf)"),
        ],
    ]
    _write(folder, OWNERS, clamped)
    trajectory, predicted, metadata = _scene()
    read = load_rollout(folder)
    assert is_sharded_rollout(folder) and read.key == "test_0000" and read.source == str(folder)
    np.testing.assert_array_equal(read.predicted, predicted)
    np.testing.assert_array_equal(read.truth.position, trajectory.position)
    np.testing.assert_array_equal(read.particle_type, trajectory.particle_type)
    np.testing.assert_array_equal(read.material_property, trajectory.material_property)
    np.testing.assert_array_equal(read.predicted_particles, trajectory.particle_type != 3)
    assert read.metadata == metadata and read.truth.walls is not None
    # One check of whole frames: step 0's non-finite particle, then step 1's escapes, merged, farthest's cause.
    merged = [(v.step, v.escaped, v.particles.tolist(), v.cause) for v in read.guard_violations]
    assert merged == [
        (0, False, [4], "have non-finite positions (NaN or Inf)"),
        (1, True, [1, 3, 6], "left (farthest: particle 6, 0.3 beyond a wall)"),
    ]


def test_a_particle_missing_or_twice_in_a_step_is_named(tmp_path):
    twice = [OWNERS[0], [OWNERS[1][0], np.array([2, 3, 4, 6, 0]), OWNERS[1][2]]]
    _write(tmp_path / "twice", twice)
    with pytest.raises(DatasetError, match=r"frames: particle 0 is in 2 shards for step 1 \(expected exactly 1\)"):
        load_sharded_rollout(tmp_path / "twice")
    missing = [OWNERS[0], [OWNERS[1][0], np.array([2, 3, 4]), OWNERS[1][2]]]
    _write(tmp_path / "missing", missing)
    with pytest.raises(DatasetError, match=r"particle 6 is in 0 shards for step 1"):
        load_sharded_rollout(tmp_path / "missing")


def test_a_missing_or_unfinished_shard_and_no_manifest_are_named(tmp_path):
    folder = tmp_path / "test_0000.rollout"
    _write(folder, OWNERS)
    (folder / "shard-00001.h5").unlink()
    with pytest.raises(DatasetError, match=r"shard-00001\.h5: shard missing \(the manifest lists 2 shards\)"):
        load_rollout(folder)
    unfinished = RolloutShard(folder, 1)
    unfinished._file.close()  # a process that stopped before its first frame
    with pytest.raises(DatasetError, match=r"shard-00001\.h5: initial/ids: missing"):
        load_rollout(folder)
    (folder / MANIFEST).unlink()
    with pytest.raises(DatasetError, match="not a sharded rollout"):
        load_rollout(folder)


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("format", "zarr", "format: expected 'gns-sharded-rollout'"),
        ("version", 2, "version: expected 1"),
        ("particles", "7", "particles: expected an integer >= 1"),
        ("dim", 4, "dim: expected an integer >= 2"),
        ("shards", ["../../etc/shard.h5"], "shards: expected a list of shard file names in the folder"),
        ("bounds", [[0, 1]], r"bounds: expected null or \(2, 2\) finite numbers"),
        ("walls", [["a", 1]] * 4, r"walls: expected null or \(4, 2\) finite numbers"),
        ("metadata", [], "metadata: expected the dataset's metadata"),
    ],
)
def test_a_wrong_manifest_field_is_named(tmp_path, field, value, message):
    folder = tmp_path / "test_0000.rollout"
    _write(folder, OWNERS)
    document = json.loads((folder / MANIFEST).read_text())
    document[field] = value
    (folder / MANIFEST).write_text(json.dumps(document))
    with pytest.raises(DatasetError, match=message):
        load_rollout(folder)


def test_a_shard_with_a_wrong_shape_or_an_id_out_of_range_is_named(tmp_path):
    folder = tmp_path / "test_0000.rollout"
    _write(folder, OWNERS)
    with h5py.File(folder / "shard-00001.h5", "r+") as shard:
        shard["frames/ids"][0] = PARTICLES
    with pytest.raises(DatasetError, match=r"shard-00001\.h5: frames/ids: expected particle ids in 0 \.\. 6"):
        load_rollout(folder)
    _write(folder, OWNERS)
    with h5py.File(folder / "shard-00000.h5", "r+") as shard:
        del shard["frames/truth"]
        shard["frames/truth"] = np.zeros((2, DIM), dtype=np.float32)
    with pytest.raises(DatasetError, match=r"shard-00000\.h5: frames/truth: expected \(13, 2\) numbers"):
        load_rollout(folder)


def test_an_abandoned_shard_leaves_nothing(tmp_path):
    shard = RolloutShard(tmp_path / "partial", 3)
    assert shard.path.name == "shard-00003.h5" and shard.path.exists()
    shard.abandon()
    assert not shard.path.exists() and not is_sharded_rollout(tmp_path / "partial")
