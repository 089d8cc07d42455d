"""Rollout files: round trip, and errors that name the file and the field."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from gns_framework.errors import DatasetError
from gns_framework.io.rollout_file import load_rollout, save_rollout


def test_round_trip_keeps_every_field(make_rollout, tmp_path):
    rollout = make_rollout(dim=3)
    loaded = load_rollout(save_rollout(tmp_path / "r.npz", rollout))
    for field in ("initial_positions", "predicted", "ground_truth", "particle_type", "material_property"):
        np.testing.assert_array_equal(getattr(loaded, field), getattr(rollout, field))
    assert loaded.metadata == rollout.metadata
    assert loaded.particle_type.dtype == np.int64 and loaded.predicted.dtype == np.float32
    assert (loaded.num_steps, loaded.num_particles, loaded.dim) == (8, 12, 3)
    assert loaded.predicted_trajectory().shape == (14, 12, 3)


def test_diverged_prediction_loads(make_rollout, tmp_path):
    rollout = make_rollout()
    predicted = rollout.predicted.copy()
    predicted[-1, 0] = np.nan
    loaded = load_rollout(save_rollout(tmp_path / "r.npz", replace(rollout, predicted=predicted)))
    assert np.isnan(loaded.predicted[-1, 0]).all()


def write_fields(path, rollout, **changes):
    fields = {
        "initial_positions": rollout.initial_positions,
        "predicted_rollout": rollout.predicted,
        "ground_truth_rollout": rollout.ground_truth,
        "particle_type": rollout.particle_type,
        "metadata_json": np.array(json.dumps(rollout.metadata.to_json_dict())),
    }
    fields.update(changes)
    np.savez(path, **{k: v for k, v in fields.items() if v is not None})
    return path


def test_a_file_written_field_by_field_loads_as_its_truth_and_prediction(make_rollout, tmp_path):
    """The file's layout is fixed: one written without the record (files from earlier versions) loads the same."""
    rollout = make_rollout()
    loaded = load_rollout(write_fields(tmp_path / "earlier.npz", rollout, material_property=rollout.material_property))
    np.testing.assert_array_equal(loaded.truth.position, rollout.truth.position)
    np.testing.assert_array_equal(loaded.predicted, rollout.predicted)
    np.testing.assert_array_equal(loaded.material_property, rollout.material_property)
    assert (loaded.history, loaded.key, loaded.source) == (6, "earlier", str(tmp_path / "earlier.npz"))


@pytest.mark.parametrize(
    "changes, field, message",
    [
        ({"particle_type": np.zeros(5, dtype=np.int64)}, "particle_type", "expected shape (12,)"),
        ({"particle_type": np.zeros(12, dtype=np.float32)}, "particle_type", "integer ids"),
        ({"predicted_rollout": np.zeros((7, 12, 2), dtype=np.float32)}, "predicted_rollout", "(8, 12, 2)"),
        ({"ground_truth_rollout": np.full((8, 12, 2), np.inf, dtype=np.float32)}, "ground_truth_rollout", "non-finite"),
        ({"initial_positions": np.zeros((6, 12, 3), dtype=np.float32)}, "initial_positions", "metadata says dim = 2"),
        ({"material_property": np.zeros((3, 2), dtype=np.float32)}, "material_property", "expected shape (12, P)"),
        ({"metadata_json": np.array("{not json")}, "metadata_json", "not valid JSON"),
        ({"metadata_json": np.array(json.dumps({"dim": 2}))}, "metadata_json", "invalid metadata"),
    ],
)
def test_malformed_field_is_named_with_the_file(make_rollout, tmp_path, changes, field, message):
    path = write_fields(tmp_path / "bad.npz", make_rollout(), **changes)
    with pytest.raises(DatasetError) as info:
        load_rollout(path)
    assert str(path) in str(info.value) and field in str(info.value) and message in str(info.value)


def test_missing_and_unknown_fields_are_listed(make_rollout, tmp_path):
    path = write_fields(tmp_path / "bad.npz", make_rollout(), particle_type=None, extra=np.zeros(1))
    with pytest.raises(DatasetError, match=r"missing field.*particle_type"):
        load_rollout(path)
    path = write_fields(tmp_path / "extra.npz", make_rollout(), extra=np.zeros(1))
    with pytest.raises(DatasetError, match=r"unknown field.*extra"):
        load_rollout(path)


def test_pickled_content_is_refused_without_unpickling(make_rollout, tmp_path):
    path = write_fields(tmp_path / "pickled.npz", make_rollout(), particle_type=np.array([object()] * 12))
    with pytest.raises(DatasetError, match="pickled"):
        load_rollout(path)


def test_missing_or_unreadable_file(tmp_path):
    with pytest.raises(DatasetError, match="not found"):
        load_rollout(tmp_path / "absent.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(DatasetError, match=r"junk\.npz: not a readable"):
        load_rollout(tmp_path / "junk.npz")
