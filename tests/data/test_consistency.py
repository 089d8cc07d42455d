"""A loaded trajectory checked against its metadata: validated, and holding the frames the metadata promises."""

from __future__ import annotations

import numpy as np
import pytest

from gns_framework.data.consistency import checked
from gns_framework.data.trajectory import Trajectory
from gns_framework.errors import DatasetError


def _trajectory(frames: int = 5, dim: int = 2) -> Trajectory:
    return Trajectory(
        np.arange(frames * 3 * dim, dtype=np.float64).reshape(frames, 3, dim), np.array([5.0, 5.0, 3.0]), key="ex_7"
    )


def test_a_trajectory_of_the_promised_length_comes_back_validated():
    valid = checked(_trajectory(5), "data/train.npz", dim=2, frames=5, promise="sequence_length 5")
    # Validated: canonical dtypes (float ids are whole numbers, so they become int64).
    assert valid.position.dtype == np.float32 and valid.particle_type.dtype == np.int64
    assert valid.particle_type.tolist() == [5, 5, 3]


def test_a_trajectory_of_another_length_names_file_trajectory_and_the_promise():
    with pytest.raises(DatasetError) as info:
        checked(_trajectory(4), "data/train.tfrecord", dim=2, frames=5, promise="sequence_length (4, one less)")
    assert str(info.value) == (
        "data/train.tfrecord: trajectory 'ex_7': position: has 4 frames but metadata.json's "
        "sequence_length (4, one less) promises 5"
    )


def test_no_promised_length_accepts_any():
    assert checked(_trajectory(9), "f.npz", dim=2, frames=None, promise="").num_steps == 9


def test_the_dimension_is_checked_before_the_length():
    with pytest.raises(DatasetError, match="'ex_7': position: has d = 3 but metadata says dim = 2"):
        checked(_trajectory(4, dim=3), "f.npz", dim=2, frames=5, promise="sequence_length")
