"""Frame strides: every k-th frame of a trajectory, a split strided on access, and a dataset whose metadata
(dt, sequence_length, statistics) is that of the strided frames."""

from __future__ import annotations

import numpy as np
import pytest

from gns_framework.contracts import Dataset, Params
from gns_framework.data.metadata import DatasetMetadata
from gns_framework.data.stride import FrameStrideDataset, StridedSplit, strided
from gns_framework.data.trajectory import Trajectory


def _accelerating(frames: int = 7, key: str = "t") -> Trajectory:
    """Particle 0 at x = t^2 / 2 (acceleration 1 per frame^2); particle 1 kinematic at x = 100 t."""
    t = np.arange(frames, dtype=np.float32)
    position = np.zeros((frames, 2, 2), np.float32)
    position[:, 0, 0] = t**2 / 2
    position[:, 1, 0] = 100 * t
    return Trajectory(position, np.array([5, 3]), step_context=t[:, None], key=key)


def test_strided_keeps_every_kth_frame_from_the_first():
    trajectory = _accelerating(7)
    every_third = strided(trajectory, 3)
    assert every_third.num_steps == 3  # frames 0, 3, 6: ceil(7 / 3)
    assert every_third.step_context[:, 0].tolist() == [0.0, 3.0, 6.0]
    np.testing.assert_array_equal(every_third.position, trajectory.position[[0, 3, 6]])
    assert strided(trajectory, 1).num_steps == 7 and every_third.key == "t"


def test_a_strided_split_strides_each_trajectory_it_hands_out():
    split = StridedSplit([_accelerating(7, "a"), _accelerating(5, "b")], 2)
    assert len(split) == 2
    assert split[1].num_steps == 3 and split[-1].key == "b"
    assert [t.num_steps for t in split[0:2]] == [4, 3]


class InMemory(Dataset):
    """A layout holding its metadata and splits in memory."""

    name = "in_memory"

    def __init__(self, splits: dict[str, list[Trajectory]]):
        super().__init__(Params(), "unused", allow_pickle=True)
        self._splits = splits

    def metadata(self):
        # The stored statistics are 99 everywhere, so that any the strided dataset passes on unchanged shows.
        stored = {"vel_mean": [99.0] * 2, "vel_std": [99.0] * 2, "acc_mean": [99.0] * 2, "acc_std": [99.0] * 2}
        bounds = [(0.0, 50.0), (0.0, 1.0)]
        return DatasetMetadata(
            bounds=bounds, sequence_length=7, default_connectivity_radius=0.1, dim=2, dt=0.01, **stored
        )

    def split(self, name):
        return self._splits[name]

    def has_split(self, name):
        return name in self._splits


def test_the_strided_dataset_steps_k_frames_at_a_time():
    inner = InMemory({"train": [_accelerating(7)], "test": [_accelerating(7)]})
    dataset = FrameStrideDataset(inner, 2, kinematic_types=[3])
    metadata = dataset.metadata()
    assert metadata.dt == pytest.approx(0.02) and metadata.sequence_length == 4  # frames 0, 2, 4, 6
    assert metadata.to_json_dict()["frame_stride"] == 2
    # Statistics recomputed, not scaled: x = t^2/2 at t = 0, 2, 4, 6 moves by 2, 6, 10 (mean 6), accelerates by
    # 4 each step (k^2 times the stored 1); the kinematic particle's 200 per step is left out.
    assert metadata.vel_mean == pytest.approx([6.0, 0.0]) and metadata.acc_mean == pytest.approx([4.0, 0.0])
    assert metadata.acc_std == pytest.approx([0.0, 0.0]) and metadata.bounds == inner.metadata().bounds
    assert dataset.metadata() is metadata  # computed once


def test_the_strided_dataset_is_the_inner_layout_otherwise():
    inner = InMemory({"valid": [_accelerating(7)]})
    dataset = FrameStrideDataset(inner, 3, kinematic_types=[3])
    assert dataset.name == "in_memory" and dataset.allow_pickle is True and dataset.inner is inner
    assert dataset.splits() == ["valid"] and not dataset.has_split("train")
    assert dataset.split("valid")[0].num_steps == 3
    # Without a train split the statistics come from the first split there is: x at t = 0, 3, 6 moves 4.5, 13.5.
    assert dataset.metadata().vel_mean == pytest.approx([9.0, 0.0])


def test_a_later_offset_starts_there_and_names_itself():
    trajectory = _accelerating(7)
    second = strided(trajectory, 3, offset=1)
    np.testing.assert_array_equal(second.position, trajectory.position[[1, 4]])
    assert second.step_context[:, 0].tolist() == [1.0, 4.0] and second.key == "t+1"
    with pytest.raises(ValueError, match=r"offset 3 must lie in \[0, 3\)"):
        strided(trajectory, 3, offset=3)


def test_a_split_with_all_offsets_hands_out_each_simulation_at_each_offset_in_turn():
    split = StridedSplit([_accelerating(8, "a"), _accelerating(8, "b")], 2, offsets=2)
    assert len(split) == 4
    assert [t.key for t in split] == ["a", "a+1", "b", "b+1"]
    assert split[-1].step_context[:, 0].tolist() == [1.0, 3.0, 5.0, 7.0]
    with pytest.raises(IndexError):
        split[4]
    with pytest.raises(ValueError, match="offsets 3"):
        StridedSplit([], 2, offsets=3)


def test_all_offsets_widen_the_train_split_only_and_its_statistics_cover_them():
    inner = InMemory({"train": [_accelerating(7)], "valid": [_accelerating(7)]})
    dataset = FrameStrideDataset(inner, 2, kinematic_types=[3], all_offsets_in_train=True)
    assert len(dataset.split("train")) == 2 and len(dataset.split("valid")) == 1
    # x = t^2/2 at t = 0, 2, 4, 6 moves by 2, 6, 10; at t = 1, 3, 5 by 4, 8: mean velocity 6 either way, and
    # the velocities' spread is that of all five steps (population std of 2, 4, 6, 8, 10 is sqrt(8)).
    metadata = dataset.metadata()
    assert metadata.vel_mean == pytest.approx([6.0, 0.0]) and metadata.vel_std[0] == pytest.approx(8**0.5)
