"""The fields of a rollout as files hold them (``gns_framework.io.rollout_fields``): a wrong one is named, the
rest become the rollout both file forms read back."""

from __future__ import annotations

import numpy as np
import pytest
from synthetic import synthetic_metadata

from gns_framework.data.trajectory import Trajectory
from gns_framework.errors import DatasetError
from gns_framework.io.rollout_fields import rollout_from_fields, validated_fields

POSITION = np.random.default_rng(0).uniform(0.1, 0.9, (5, 4, 2)).astype(np.float32)
METADATA = synthetic_metadata([Trajectory(POSITION, np.array([5, 5, 6, 3]))], 2)


def _fields() -> dict:
    position = POSITION
    return {
        "initial_positions": position[:2],
        "predicted_rollout": position[2:] + 0.01,
        "ground_truth_rollout": position[2:],
        "particle_type": np.array([5, 5, 6, 3]),
        "material_property": np.array([0.5, 0.6, 0.7, 0.8]),  # one property, as a vector
        "bounds": None,
        "walls": None,
    }


def test_the_fields_make_the_rollout_with_canonical_dtypes():
    rollout = rollout_from_fields("x.npz", _fields(), METADATA, "x")
    assert rollout.key == "x" and rollout.history == 2 and rollout.num_steps == 3
    assert rollout.material_property is not None and rollout.material_property.shape == (4, 1)
    assert rollout.particle_type.dtype == np.int64 and rollout.predicted.dtype == np.float32


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("ground_truth_rollout", np.zeros((3, 5, 2), np.float32), r"ground_truth_rollout: expected shape \(S, 4, 2\)"),
        ("predicted_rollout", np.zeros((2, 4, 2), np.float32), "predicted_rollout: expected shape"),
        ("particle_type", np.array([5, 5, -1, 3]), "particle_type: ids must be >= 0"),
        ("material_property", np.array([0.5, np.nan, 0.7, 0.8]), "material_property: non-finite value"),
        ("bounds", np.array([[1.0, 0.0], [0.0, 1.0]]), "bounds: expected \\[lower, upper\\] with lower < upper"),
    ],
)
def test_a_wrong_field_is_named_with_its_file(field, value, message):
    fields = {**_fields(), field: value}
    with pytest.raises(DatasetError, match=f"x.npz.*{message}"):
        validated_fields("x.npz", fields, METADATA)
