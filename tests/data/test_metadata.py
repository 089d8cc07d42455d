"""Dataset metadata: what DatasetMetadata refuses, the geoelements per-split form, the bounded reading of
metadata.json, and the normalisation statistics computed from trajectories."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from pydantic import ValidationError

from gns_framework.data import metadata as metadata_module
from gns_framework.data.metadata import (
    DatasetMetadata,
    compute_statistics,
    load_metadata,
    parse_metadata,
    read_metadata_json,
)
from gns_framework.data.trajectory import Trajectory
from gns_framework.errors import DatasetError

RAW = {
    "bounds": [[0.1, 0.9], [0.1, 0.9]],
    "sequence_length": 320,
    "default_connectivity_radius": 0.015,
    "dim": 2,
    "dt": 0.0025,
    "vel_mean": [0.0, -0.001],
    "vel_std": [0.002, 0.003],
    "acc_mean": [0.0, 0.0],
    "acc_std": [0.0001, 0.0002],
}


def test_a_valid_mapping_keeps_unknown_keys_and_writes_back_without_the_absent_ones():
    metadata = DatasetMetadata.model_validate({**RAW, "frame_stride": 2})
    assert metadata.boundary_clamp_limit == 1.0  # geoelements' boundary_augment absent
    written = metadata.to_json_dict()
    assert written["frame_stride"] == 2 and "context_mean" not in written and "boundary_augment" not in written
    assert DatasetMetadata.model_validate(written) == metadata


def test_boundary_augment_is_the_clamp_limit():
    assert DatasetMetadata.model_validate({**RAW, "boundary_augment": 1.5}).boundary_clamp_limit == 1.5


@pytest.mark.parametrize(
    "change, message",
    [
        ({"vel_std": [0.002]}, "vel_std has 1 entries but dim = 2"),
        ({"bounds": [[0.1, 0.9]] * 3}, "bounds has 3 entries but dim = 2"),
        ({"acc_std": [0.1, -0.1]}, "acc_std must be finite and >= 0"),
        ({"vel_mean": [math.nan, 0.0]}, "vel_mean must be finite"),
        ({"dt": math.inf}, "dt must be finite"),
        ({"bounds": [[0.9, 0.1], [0.1, 0.9]]}, "lower < upper"),
        ({"periodic_boundary_conditions": [True]}, "periodic_boundary_conditions has 1 entries but dim = 2"),
        ({"context_mean": [0.0]}, "context_mean and context_std must be given together"),
        ({"context_mean": [0.0], "context_std": [1.0, 1.0]}, "must have the same length"),
        ({"sequence_length": 10**7}, "more than the limit of 1,000,000"),
        ({"sequence_length": 1}, "greater than 1"),
        ({"dim": 4}, "less than or equal to 3"),
    ],
)
def test_inconsistent_metadata_is_refused_saying_what_is_wrong(change, message):
    with pytest.raises(ValidationError, match=message):
        DatasetMetadata.model_validate({**RAW, **change})


def test_parse_metadata_names_the_file_and_every_field_in_one_line():
    raw = {k: v for k, v in RAW.items() if k != "dt"} | {"dim": 5}
    with pytest.raises(DatasetError) as info:
        parse_metadata(raw, "data/metadata.json")
    message = str(info.value)
    assert message.startswith("data/metadata.json: invalid metadata: ") and "\n" not in message
    assert "dim: " in message and "dt: Field required" in message


def test_geoelements_metadata_per_split_takes_the_asked_split_then_train():
    nested = {"train": RAW, "rollout": {**RAW, "sequence_length": 400}}
    assert parse_metadata(nested, "m.json", split="rollout").sequence_length == 400
    assert parse_metadata(nested, "m.json", split="valid").sequence_length == 320  # no valid entry: train's
    assert parse_metadata(nested, "m.json").sequence_length == 320
    assert parse_metadata({"rollout": RAW}, "m.json").sequence_length == 320  # no train entry: the only one


def test_load_metadata_takes_a_folder_or_the_file_itself(tmp_path):
    (tmp_path / "metadata.json").write_text(json.dumps(RAW))
    assert load_metadata(tmp_path) == load_metadata(tmp_path / "metadata.json") == DatasetMetadata(**RAW)


@pytest.mark.parametrize(
    "content, message",
    [
        (b'{"dim": 2', "not valid JSON (Expecting ',' delimiter at line 1)"),
        (b"[1, 2]", "expected a JSON object, got list"),
        (b'{"name": "caf\xe9"}', "not UTF-8 text (byte 13 is 0xe9)"),
    ],
)
def test_a_file_that_is_no_json_object_is_refused_naming_it(tmp_path, content, message):
    path = tmp_path / "metadata.json"
    path.write_bytes(content)
    with pytest.raises(DatasetError) as info:
        read_metadata_json(path)
    assert str(info.value) == f"{path}: {message}"


def test_a_missing_file_is_named(tmp_path):
    with pytest.raises(DatasetError, match=r"metadata.json: metadata file not found"):
        load_metadata(tmp_path)


def test_a_file_longer_than_the_limit_is_refused_without_reading_it_all(tmp_path, monkeypatch):
    monkeypatch.setattr(metadata_module, "MAX_METADATA_BYTES", 2**20)  # 1 MiB, so the test writes little
    path = tmp_path / "metadata.json"
    path.write_bytes(b" " * (2**20 + 1))
    with pytest.raises(DatasetError, match="more than 1 MiB, too large for a metadata file"):
        read_metadata_json(path)
    path.write_bytes(b" " * (2**20 - 2) + b"{}")  # exactly the limit is still read
    assert read_metadata_json(path) == {}


def test_statistics_are_those_of_the_finite_differences_of_moving_particles():
    # Particle 0 moves along x by 1, 2, 3, 4 per frame (accelerations 1, 1, 1); particle 1 along y by 0, 2, 0, 2
    # (accelerations 2, -2, 2); particle 2 is kinematic and jumps wildly, so it must be left out.
    position = np.zeros((5, 3, 2))
    position[:, 0, 0] = [0, 1, 3, 6, 10]
    position[:, 1, 1] = [0, 0, 2, 2, 4]
    position[:, 2, :] = [[0, 0], [50, 50], [-50, 0], [50, 50], [0, 0]]
    stats = compute_statistics([Trajectory(position.astype(np.float32), np.array([5, 6, 3]))], kinematic_types=[3])
    # The positions are small whole numbers, exact in float32, and the sums are float64: approx's default
    # relative 1e-6 is far looser than the rounding, far tighter than any mistake in what is counted.
    # Velocities of x: 1, 2, 3, 4 and 0, 0, 0, 0 -> mean 1.25, var = 30/8 - 1.25^2; of y: 0 x 4 and 0, 2, 0, 2.
    assert stats["vel_mean"] == pytest.approx([1.25, 0.5])
    assert stats["vel_std"] == pytest.approx([math.sqrt(30 / 8 - 1.25**2), math.sqrt(8 / 8 - 0.5**2)])
    # Accelerations of x: 1, 1, 1 and 0, 0, 0 -> mean 0.5, std 0.5; of y: 0 x 3 and 2, -2, 2 -> mean 1/3.
    assert stats["acc_mean"] == pytest.approx([0.5, 1 / 3])
    assert stats["acc_std"] == pytest.approx([0.5, math.sqrt(12 / 6 - 1 / 9)])
    assert "context_mean" not in stats


def test_statistics_pool_trajectories_and_include_the_context():
    still = Trajectory(np.zeros((4, 1, 2), np.float32), np.array([5]), step_context=np.array([[1.0], [3.0]] * 2))
    moving = Trajectory(np.arange(8, dtype=np.float32).reshape(4, 1, 2) * 0.5, np.array([5]))
    stats = compute_statistics([still, moving], kinematic_types=())
    # Three zero velocities and three of 1.0 per component: mean 0.5, std 0.5.
    assert stats["vel_mean"] == pytest.approx([0.5, 0.5]) and stats["vel_std"] == pytest.approx([0.5, 0.5])
    assert stats["context_mean"] == pytest.approx([2.0]) and stats["context_std"] == pytest.approx([1.0])


def test_statistics_need_three_frames_of_a_moving_particle():
    short = Trajectory(np.zeros((2, 2, 2), np.float32), np.array([5, 5]))
    only_kinematic = Trajectory(np.zeros((5, 2, 2), np.float32), np.array([3, 3]))
    with pytest.raises(DatasetError, match="none of its 2 trajectories has 3 frames of non-kinematic particles"):
        compute_statistics([short, only_kinematic], kinematic_types=[3])


def test_statistics_of_no_trajectory_name_the_dataset_and_split():
    from gns_framework.data.metadata import compute_statistics

    with pytest.raises(
        DatasetError, match=r"^data/x \(split train\): cannot compute statistics: holds 0 trajectories$"
    ):
        compute_statistics([], (3,), "data/x (split train)")
