"""What every layout reads through: metadata errors, trajectory validation and statistics.

Each layout's own round trip and errors are tested in its mirror (test_safe.py, test_npz.py,
test_tfrecord.py, test_lagrangebench.py).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from gns_framework.data.metadata import compute_statistics, load_metadata
from gns_framework.data.trajectory import Trajectory
from gns_framework.errors import DatasetError


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
