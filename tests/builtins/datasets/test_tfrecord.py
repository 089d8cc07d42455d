"""DeepMind's TFRecord layout: read as DeepMind writes it, round trips of the extra fields, located errors."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from layout_fixtures import FIXTURES, FLOAT32, expected_position, read
from synthetic import synthetic_metadata

from gns_builtins.datasets._formats.tfrecord_format import Feature, SequenceExample, read_records, write_records
from gns_builtins.datasets.tfrecord import TfRecordDataset
from gns_framework.errors import DatasetError


def test_deepmind_tfrecord_is_read_as_written(registry):
    metadata, splits = read(registry, "tfrecord", FIXTURES / "deepmind")
    # DeepMind's sequence_length 3 counts steps: 4 frames.
    assert metadata.sequence_length == 4 and metadata.dt == 0.0025 and metadata.dim == 2
    assert metadata.bounds == [(0.1, 0.9), (0.1, 0.9)] and metadata.default_connectivity_radius == 0.015
    assert list(splits) == ["train", "test"]
    train, test = splits["train"], splits["test"]
    assert [t.key for t in train] == ["0", "1"] and [t.key for t in test] == ["1"]
    np.testing.assert_array_equal(train[0].particle_type, [6, 6, 3])
    np.testing.assert_array_equal(train[1].particle_type, [5, 5, 5, 3])
    np.testing.assert_array_equal(test[0].particle_type, [6, 3])
    np.testing.assert_allclose(train[1].position, expected_position(4, 4, 1), rtol=FLOAT32)
    np.testing.assert_allclose(test[0].position, expected_position(4, 2, 1), rtol=FLOAT32)
    np.testing.assert_allclose(train[1].position[3, 2], [0.48, 0.44], rtol=FLOAT32)
    assert train[0].material_property is None and train[0].step_context is None


def dataset(path) -> TfRecordDataset:
    return TfRecordDataset(TfRecordDataset.Params(), path)


def test_material_properties_step_context_and_names_round_trip(trajectories, tmp_path):
    frames = trajectories[0].num_steps
    first = replace(trajectories[0], step_context=np.linspace(0, 1, 3 * frames, dtype=np.float32).reshape(frames, 3))
    second = replace(
        trajectories[1],
        material_property=np.stack([np.linspace(0, 1, trajectories[1].num_particles)] * 2, 1).astype(np.float32),
    )
    metadata = synthetic_metadata(trajectories, 2)
    TfRecordDataset.write(tmp_path, metadata, {"train": [first, second]})
    # 12 frames are 11 steps in DeepMind's metadata.json, 12 frames again when read.
    assert json.loads((tmp_path / "metadata.json").read_text())["sequence_length"] == 11
    assert dataset(tmp_path).metadata() == metadata
    back = dataset(tmp_path).split("train")
    assert [t.key for t in back] == ["a", "b"]
    for original, loaded in zip((first, second), back, strict=True):
        for field in ("position", "particle_type", "material_property", "step_context"):
            np.testing.assert_array_equal(getattr(loaded, field), getattr(original, field), err_msg=field)


def test_numbered_trajectories_keep_their_numbers_and_need_no_name(trajectories, tmp_path):
    numbered = [replace(trajectories[0], key="3"), replace(trajectories[1], key="5")]
    TfRecordDataset.write(tmp_path, synthetic_metadata(trajectories, 2), {"test": numbered})
    records = [SequenceExample.parse(r) for r in read_records(tmp_path / "test.tfrecord")]
    assert [int(r.context["key"].values[0]) for r in records] == [3, 5]
    assert all("trajectory_key" not in r.context for r in records)
    assert [t.key for t in dataset(tmp_path).split("test")] == ["3", "5"]


def test_trajectories_of_another_length_are_refused_before_any_file_is_written(trajectories, tmp_path):
    short = replace(trajectories[1], position=trajectories[1].position[:6])
    with pytest.raises(
        DatasetError, match=r"valid\.tfrecord: trajectory 'b': position: has 6 frames, .* it is 12 frames"
    ):
        TfRecordDataset.write(tmp_path, synthetic_metadata(trajectories, 2), {"train": trajectories, "valid": [short]})
    assert list(tmp_path.iterdir()) == []


def write_records_of(tmp_path, trajectories, *examples: SequenceExample) -> TfRecordDataset:
    """A dataset whose train split holds ``examples`` as they are, with the metadata of ``trajectories`` (2D, 12
    frames)."""
    TfRecordDataset.write(tmp_path, synthetic_metadata(trajectories, 2), {"train": trajectories[:1]})
    write_records(tmp_path / "train.tfrecord", [example.serialize() for example in examples])
    return dataset(tmp_path)


def frames_of(values: np.ndarray) -> list[Feature]:
    return [Feature("bytes", [np.asarray(frame, "<f4").tobytes()]) for frame in values]


def types_of(types) -> Feature:
    return Feature("bytes", [np.asarray(types, "<i8").tobytes()])


def test_a_frame_of_the_wrong_size_is_located(trajectories, tmp_path):
    # Three particles in 2D are 6 floats per frame; these frames hold 4.
    bad = SequenceExample({"particle_type": types_of([5, 5, 5])}, {"position": frames_of(np.zeros((12, 4)))})
    with pytest.raises(DatasetError, match=r"trajectory 0: position: expected 3 x 2 = 6 floats per frame, got \[4\]"):
        write_records_of(tmp_path, trajectories, bad).split("train")[0]


def test_a_missing_field_is_located(trajectories, tmp_path):
    bad = SequenceExample({}, {"position": frames_of(np.zeros((12, 6)))})
    with pytest.raises(DatasetError, match=r"train\.tfrecord: trajectory 0: particle_type: missing"):
        write_records_of(tmp_path, trajectories, bad).split("train")[0]


def test_material_properties_that_do_not_split_over_the_particles_are_located(trajectories, tmp_path):
    context = {
        "particle_type": types_of([5, 5, 5]),
        "material_property": Feature("bytes", [np.zeros(4, "<f4").tobytes()]),
    }
    bad = SequenceExample(context, {"position": frames_of(np.zeros((12, 6)))})
    with pytest.raises(DatasetError, match=r"material_property: 4 floats do not split over 3 particles"):
        write_records_of(tmp_path, trajectories, bad).split("train")[0]


def test_a_feature_of_another_kind_is_located(trajectories, tmp_path):
    # particle_type as int64 values, where the layout stores one bytes value.
    bad = SequenceExample(
        {"particle_type": Feature("int64", np.array([5, 5, 5]))}, {"position": frames_of(np.zeros((12, 6)))}
    )
    with pytest.raises(DatasetError, match=r"particle_type: expected one bytes value, got int64 x 3"):
        write_records_of(tmp_path, trajectories, bad).split("train")[0]


def test_a_record_that_is_not_a_sequence_example_is_located(trajectories, tmp_path):
    TfRecordDataset.write(tmp_path, synthetic_metadata(trajectories, 2), {"train": trajectories[:1]})
    # Field 1 with wire type 7, which protobuf does not have.
    write_records(tmp_path / "train.tfrecord", [b"\x0f"])
    with pytest.raises(DatasetError, match=r"train\.tfrecord: trajectory 0: not a SequenceExample"):
        dataset(tmp_path).split("train")[0]


def test_checksums_are_verified_unless_the_params_say_not_to(trajectories, tmp_path):
    TfRecordDataset.write(tmp_path, synthetic_metadata(trajectories, 2), {"train": trajectories[:1]})
    file = tmp_path / "train.tfrecord"
    data = bytearray(file.read_bytes())
    data[-1] ^= 0xFF  # the data checksum of the last record; the record itself is intact
    file.write_bytes(bytes(data))
    with pytest.raises(DatasetError, match=r"train\.tfrecord: record 0: data checksum mismatch"):
        dataset(tmp_path).split("train")
    unchecked = TfRecordDataset(TfRecordDataset.Params(verify_checksums=False), tmp_path)
    np.testing.assert_array_equal(unchecked.split("train")[0].position, trajectories[0].position)


def test_splits_are_the_files_present(trajectories, tmp_path):
    TfRecordDataset.write(tmp_path, synthetic_metadata(trajectories, 2), {"valid": trajectories})
    assert dataset(tmp_path).splits() == ["valid"]
    with pytest.raises(DatasetError, match=r"train\.tfrecord: split file not found"):
        dataset(tmp_path).split("train")
