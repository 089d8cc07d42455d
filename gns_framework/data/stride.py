"""A dataset seen every k-th stored frame: one learned step spans k frames of the simulator's output.

Particle solvers store frames far more often than a learned simulator needs to
step: between two stored frames of a slow granular flow the particles move a
fraction of their spacing. Learning one step over k frames makes a rollout k
times shorter, so it costs k times less and accumulates error over k times fewer
steps. The statistics that normalise the model's inputs and outputs change with
k (velocities grow about k-fold, accelerations about k^2-fold), so they are
recomputed from the strided trajectories rather than scaled.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import replace

from ..contracts import Dataset
from .metadata import DatasetMetadata, compute_statistics
from .trajectory import Trajectory


def strided(trajectory: Trajectory, stride: int) -> Trajectory:
    """Every ``stride``-th frame of ``trajectory``, starting with the first.

    Shapes: position (T, N, d) -> (ceil(T / stride), N, d); step_context likewise.
    """
    context = None if trajectory.step_context is None else trajectory.step_context[::stride]
    return replace(trajectory, position=trajectory.position[::stride], step_context=context)


class StridedSplit(Sequence[Trajectory]):
    """A split whose trajectories are strided on access (the underlying split stays lazy)."""

    def __init__(self, split: Sequence[Trajectory], stride: int):
        self._split = split
        self._stride = stride

    def __len__(self) -> int:
        return len(self._split)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        return strided(self._split[index], self._stride)


class FrameStrideDataset(Dataset):
    """``dataset`` with every ``stride``-th frame: ``dt`` is ``stride`` times the stored one.

    The metadata's velocity and acceleration statistics are those of the strided
    frames, computed on the train split (or, where a folder has none, the first
    split it holds); ``frame_stride`` records the stride applied.
    """

    def __init__(self, dataset: Dataset, stride: int, kinematic_types: Collection[int]):
        """``kinematic_types``: the particle types the statistics leave out (kinematic materials)."""
        super().__init__(dataset.params, dataset.path, allow_pickle=dataset.allow_pickle)
        self.name = dataset.name  # type: ignore[misc]  # the wrapped layout's name, per instance (a ClassVar elsewhere)
        self.inner = dataset
        self.stride = stride
        self.kinematic_types = tuple(kinematic_types)
        self._metadata: DatasetMetadata | None = None

    def metadata(self) -> DatasetMetadata:
        if self._metadata is None:
            stored = self.inner.metadata()
            splits = self.splits()
            measured = "train" if "train" in splits else splits[0] if splits else None
            statistics = (
                compute_statistics(self.split(measured), self.kinematic_types, f"{self.path} (split {measured})")
                if measured is not None
                else {}
            )
            frames = -(-stored.sequence_length // self.stride)
            self._metadata = stored.model_copy(
                update={
                    "dt": stored.dt * self.stride,
                    "sequence_length": frames,
                    "frame_stride": self.stride,
                    **statistics,
                }
            )
        return self._metadata

    def split(self, name: str) -> Sequence[Trajectory]:
        return StridedSplit(self.inner.split(name), self.stride)

    def has_split(self, name: str) -> bool:
        return self.inner.has_split(name)
