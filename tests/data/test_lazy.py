"""A split read lazily: each trajectory loaded on first access only, validated against the metadata's dim, then kept."""

from __future__ import annotations

import numpy as np
import pytest

from gns_framework.data.lazy import TrajectorySequence
from gns_framework.data.trajectory import Trajectory
from gns_framework.errors import DatasetError


class Loader:
    """Reads trajectory ``key`` as frames filled with its number, counting the reads."""

    def __init__(self, dim: int = 2):
        self.reads: list[str] = []
        self.dim = dim

    def __call__(self, key: str) -> Trajectory:
        self.reads.append(key)
        value = float(key.split("_")[1])
        position = np.full((3, 2, self.dim), value)
        position[:, 1] += 0.5  # two particles, apart
        return Trajectory(position, np.array([5, 5]), key=key)


KEYS = ["t_0", "t_1", "t_2", "t_3"]


def test_nothing_is_read_until_asked_for_and_nothing_twice():
    load = Loader()
    split = TrajectorySequence(KEYS, load, "data/train.npz", dim=2)
    assert len(split) == 4 and load.reads == []
    first = split[2]
    assert first.position[0, 0, 0] == 2.0 and first.position.dtype == np.float32  # validated on the way
    assert split[2] is first and load.reads == ["t_2"]


def test_negative_indices_and_slices_read_the_trajectories_they_name():
    load = Loader()
    split = TrajectorySequence(KEYS, load, "data/train.npz", dim=2)
    assert split[-1].key == "t_3"
    assert [t.key for t in split[1:4:2]] == ["t_1", "t_3"]
    assert [t.key for t in split] == KEYS  # iterating stops at the end (IndexError)
    assert load.reads == ["t_3", "t_1", "t_0", "t_2"]


@pytest.mark.parametrize("index", [4, -5])
def test_an_index_outside_the_split_is_an_index_error(index):
    with pytest.raises(IndexError):
        TrajectorySequence(KEYS, Loader(), "f.npz", dim=2)[index]


def test_a_trajectory_of_another_dimension_names_the_file_and_trajectory():
    split = TrajectorySequence(KEYS, Loader(dim=3), "data/valid.npz", dim=2)
    with pytest.raises(DatasetError, match=r"data/valid.npz: trajectory 't_1': position: has d = 3"):
        split[1]


def test_with_keep_only_the_most_recently_used_trajectories_stay_and_the_others_are_read_again():
    load = Loader()
    split = TrajectorySequence(KEYS, load, "data/train.npz", dim=2, keep=2)
    first = split[0]
    split[1], split[0], split[2]  # t_1 is now the least recently used
    assert split[0] is first and load.reads == ["t_0", "t_1", "t_2"]
    again = split[1]  # evicted: read again, the same values
    assert load.reads == ["t_0", "t_1", "t_2", "t_1"]
    assert again.position[0, 0, 0] == 1.0
    split[3]  # keeps t_1 and t_3: t_0 and t_2 are read again when asked for
    assert split[1] is again
    split[0]
    assert load.reads == ["t_0", "t_1", "t_2", "t_1", "t_3", "t_0"]


def test_a_split_file_rewritten_between_two_reads_is_refused_before_the_second(tmp_path):
    import os

    from gns_framework.data.file_identity import DatasetChanged

    source = tmp_path / "train.npz"
    source.write_bytes(b"x" * 100)
    split = TrajectorySequence(KEYS, Loader(), str(source), dim=2)
    split[0]
    stat = source.stat()
    os.utime(source, ns=(stat.st_atime_ns, stat.st_mtime_ns + 1_000_000))  # rewritten in place, the same size
    with pytest.raises(DatasetChanged, match=rf"^{source}: changed while it was being read \(it was rewritten"):
        split[1]
    source.unlink()
    with pytest.raises(DatasetChanged, match=r"\(it is gone\)"):
        split[2]
