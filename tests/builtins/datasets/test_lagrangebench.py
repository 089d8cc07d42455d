"""LagrangeBench's HDF5 layout: read as LagrangeBench defines it, its metadata written back in its terms."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace

import h5py
import numpy as np
import pytest
from layout_fixtures import FIXTURES, FLOAT32, expected_position, read
from synthetic import synthetic_metadata

from gns_builtins.datasets.lagrangebench import LagrangeBenchDataset, lagrangebench_metadata
from gns_framework.data.trajectory import Trajectory
from gns_framework.errors import DatasetError


def test_lagrangebench_is_read_as_lagrangebench_defines_it(registry):
    metadata, splits = read(registry, "lagrangebench", FIXTURES / "lagrangebench")
    # sequence_length_train 4 counts steps: 5 frames; dt is the solver step, frames are write_every steps apart.
    assert metadata.sequence_length == 5
    assert metadata.dt == pytest.approx(0.0007 * 100, rel=1e-12)
    extra = metadata.model_extra
    assert extra["solver_dt"] == 0.0007 and extra["write_every"] == 100
    assert extra["solver"] == "SPH" and extra["dx"] == 0.1 and extra["case"] == "TGV"
    # Three entries in 2D, as LagrangeBench writes them: the first two are the axes.
    assert metadata.periodic_boundary_conditions == [True, True]
    assert {name: [t.num_steps for t in trajectories] for name, trajectories in splits.items()} == {
        "train": [5, 5],
        "valid": [4],
        "test": [4],  # valid: no sequence_length_valid, taken from the file
    }
    assert [t.key for t in splits["train"]] == ["00000", "00001"]
    np.testing.assert_array_equal(splits["train"][1].particle_type, [0, 0, 0])
    assert splits["train"][1].particle_type.dtype == np.int64
    np.testing.assert_allclose(splits["train"][1].position, expected_position(5, 3, 1), rtol=FLOAT32)
    np.testing.assert_allclose(splits["test"][0].position, expected_position(4, 3, 0), rtol=FLOAT32)


def test_lagrangebench_length_disagreeing_with_its_metadata_is_located(registry, tmp_path):
    shutil.copytree(FIXTURES / "lagrangebench", tmp_path / "lb")
    file = tmp_path / "lb" / "metadata.json"
    file.write_text(json.dumps({**json.loads(file.read_text()), "sequence_length_test": 4}))
    with pytest.raises(
        DatasetError,
        match=r"test\.h5: trajectory '00000': position: has 4 frames but metadata\.json's "
        r"sequence_length_test = 4 .* promises 5",
    ):
        read(registry, "lagrangebench", tmp_path / "lb")


def lagrangebench_copy(tmp_path, **changes):
    """The fixture dataset copied, with ``changes`` to its metadata.json (None deletes a key)."""
    shutil.copytree(FIXTURES / "lagrangebench", tmp_path / "lb")
    file = tmp_path / "lb" / "metadata.json"
    raw = {**json.loads(file.read_text()), **changes}
    file.write_text(json.dumps({k: v for k, v in raw.items() if v is not None}))
    return LagrangeBenchDataset(LagrangeBenchDataset.Params(), tmp_path / "lb")


def test_without_a_training_length_the_sequence_length_is_the_first_trajectorys(tmp_path):
    # train.h5 holds trajectories of 5 frames.
    assert lagrangebench_copy(tmp_path, sequence_length_train=None).metadata().sequence_length == 5


@pytest.mark.parametrize("steps", [0, "4"])
def test_a_split_length_that_is_not_a_positive_integer_is_located(tmp_path, steps):
    dataset = lagrangebench_copy(tmp_path, sequence_length_test=steps)
    with pytest.raises(
        DatasetError, match=rf"metadata\.json: sequence_length_test: expected an integer >= 1, got {steps!r}"
    ):
        dataset.split("test")


def test_a_damaged_split_file_is_located(tmp_path):
    dataset = lagrangebench_copy(tmp_path)
    (tmp_path / "lb" / "valid.h5").write_bytes(b"\x89HDF\r\n\x1a\n truncated")
    with pytest.raises(DatasetError, match=r"valid\.h5: not a readable HDF5 file \(truncated or corrupt\?\)"):
        dataset.split("valid")
    with pytest.raises(DatasetError, match=r"train2\.h5: split file not found"):
        dataset.split("train2")


def test_a_group_without_particle_types_is_located(tmp_path):
    dataset = lagrangebench_copy(tmp_path)
    with h5py.File(tmp_path / "lb" / "valid.h5", "a") as handle:
        del handle["00000"]["particle_type"]
    with pytest.raises(DatasetError, match=r"valid\.h5: trajectory '00000': particle_type: missing"):
        dataset.split("valid")[0]


def test_names_optional_fields_and_lengths_per_split_round_trip(trajectories, tmp_path):
    frames = trajectories[0].num_steps
    with_context = replace(trajectories[0], step_context=np.ones((frames, 2), np.float32))
    short = replace(trajectories[1], key="7", position=trajectories[1].position[:6])
    metadata = synthetic_metadata(trajectories, 2)
    LagrangeBenchDataset.write(tmp_path, metadata, {"train": [with_context, trajectories[1]], "test": [short]})
    with h5py.File(tmp_path / "train.h5", "r") as handle:
        # Groups are numbered; a name that is not its group's rides along as the key attribute.
        assert list(handle) == ["00000", "00001"] and handle["00000"].attrs["key"] == "a"
    with h5py.File(tmp_path / "test.h5", "r") as handle:
        # Trajectory 7 is stored in group 7; its name "7" is not the group's "00007", so it rides along too.
        assert list(handle) == ["00007"] and handle["00007"].attrs["key"] == "7"
    written = json.loads((tmp_path / "metadata.json").read_text())
    assert (written["sequence_length_train"], written["num_trajs_train"]) == (11, 2)
    assert (written["sequence_length_test"], written["num_trajs_test"]) == (5, 1)
    dataset = LagrangeBenchDataset(LagrangeBenchDataset.Params(), tmp_path)
    assert dataset.metadata().sequence_length == 12
    train, test = dataset.split("train"), dataset.split("test")
    assert [t.key for t in train] == ["a", "b"] and [t.key for t in test] == ["7"]
    np.testing.assert_array_equal(train[0].step_context, with_context.step_context)
    np.testing.assert_array_equal(train[1].material_property, trajectories[1].material_property)
    np.testing.assert_array_equal(test[0].position, short.position)


def grid_trajectory(spacing: float, frames: int = 3, key: str = "") -> Trajectory:
    """Four particles on a square of side ``spacing``: each one's nearest neighbour is ``spacing`` away."""
    square = np.array([[0.2, 0.2], [0.2 + spacing, 0.2], [0.2, 0.2 + spacing], [0.2 + spacing, 0.2 + spacing]])
    return Trajectory(np.repeat(square[None], frames, 0).astype(np.float32), np.zeros(4, np.int64), key=key)


def test_metadata_is_written_in_lagrangebench_terms(tmp_path):
    trajectory = grid_trajectory(0.05)
    base = synthetic_metadata([trajectory], 2)
    # As read from LagrangeBench's files: a frame every 100 solver steps of 0.0007 s.
    metadata = base.model_copy(update={"dt": 0.0007 * 100, "solver_dt": 0.0007, "write_every": 100})
    document = lagrangebench_metadata(tmp_path, metadata, {"train": [trajectory], "valid": [trajectory] * 2})
    assert "sequence_length" not in document and "solver_dt" not in document
    assert document["dt"] == 0.0007, "the solver step again"
    assert (document["sequence_length_train"], document["num_trajs_train"]) == (2, 1)
    assert (document["sequence_length_valid"], document["num_trajs_valid"]) == (2, 2)
    assert document["periodic_boundary_conditions"] == [False, False]
    assert document["num_particles_max"] == 4
    # The median nearest-neighbour distance of the first frame.
    assert document["dx"] == pytest.approx(0.05, rel=1e-6)


def test_a_frame_stride_since_reading_changes_the_solver_step_it_writes(tmp_path):
    # Every second frame kept: frames 0.14 s apart, so 100 solver steps are 0.0014 s each, not the stored 0.0007.
    trajectory = grid_trajectory(0.05)
    metadata = synthetic_metadata([trajectory], 2).model_copy(
        update={"dt": 0.14, "solver_dt": 0.0007, "write_every": 100, "dx": 0.02, "num_particles_max": 9}
    )
    document = lagrangebench_metadata(tmp_path, metadata, {"train": [trajectory]})
    assert document["dt"] == pytest.approx(0.0014, rel=1e-12)
    # What the metadata already says is kept: its spacing, and a larger particle count than this split's.
    assert document["dx"] == 0.02 and document["num_particles_max"] == 9


def test_a_split_of_several_lengths_is_refused(tmp_path):
    metadata = synthetic_metadata([grid_trajectory(0.05)], 2)
    with pytest.raises(DatasetError, match=r"train\.h5: trajectories of \[3, 5\] frames, but LagrangeBench's layout"):
        LagrangeBenchDataset.write(tmp_path, metadata, {"train": [grid_trajectory(0.05), grid_trajectory(0.05, 5)]})
    assert not (tmp_path / "train.h5").exists()


def test_a_dataset_declaring_terabytes_it_does_not_store_is_refused_before_h5py_allocates(tmp_path):
    """A chunked HDF5 dataset may declare any shape: unwritten chunks read as the fill value (issue 47)."""
    from gns_builtins.datasets.lagrangebench import read_bounded
    from gns_framework.limits import LimitError

    path = tmp_path / "train.h5"
    with h5py.File(path, "w") as handle:
        group = handle.create_group("00000")
        group.create_dataset("position", shape=(10_000, 100_000_000, 3), dtype="f4", chunks=(1, 1000, 3))
        group.create_dataset("particle_type", data=np.zeros(4, np.int64))
    assert path.stat().st_size < 100_000
    with h5py.File(path, "r") as handle:
        with pytest.raises(
            LimitError, match=r"^x: position: declares 12,000,000,000,000 bytes \(10000, 100000000, 3\)"
        ):
            read_bounded(handle["00000"], "position", "x")
        assert read_bounded(handle["00000"], "particle_type", "x").shape == (4,)


def test_damaged_hdf5_is_one_line_naming_the_file_and_what_was_read():
    from pathlib import Path

    from gns_builtins.datasets.lagrangebench import damaged_hdf5
    from gns_framework.errors import DatasetError

    with (
        pytest.raises(
            DatasetError,
            match=r"^f\.h5: not a readable HDF5 file \(truncated or corrupt\?\) reading "
            r"trajectory '3': Unable to get group info \(bad symbol table node signature\)$",
        ),
        damaged_hdf5(Path("f.h5"), "trajectory '3'"),
    ):
        raise RuntimeError("Unable to get group info (bad symbol table node signature)")
