"""A dataset seen every k-th stored frame: one learned step spans k frames of the simulator's output.

Particle solvers store frames far more often than a learned simulator needs to
step: between two stored frames of a slow granular flow the particles move a
fraction of their spacing. Learning one step over k frames makes a rollout k
times shorter, so it costs k times less and accumulates error over k times fewer
steps. The statistics that normalise the model's inputs and outputs change with
k (velocities grow about k-fold, accelerations about k^2-fold), so they are
recomputed from the strided trajectories rather than scaled.

Every offset of a trajectory is a trajectory of the same physics: frames j, j + k,
j + 2k, ... for j < k. Training may take all k (``stride_offsets: all``), which gives
k times the windows of the first offset alone from the same simulations; rollouts
and validation start, as a user's scene does, from the first frame.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import replace

from ..contracts import Dataset
from .in_parts import scene_in_parts
from .lazy import Split
from .metadata import DatasetMetadata, compute_statistics
from .trajectory import Trajectory


def strided(trajectory: Trajectory, stride: int, offset: int = 0) -> Trajectory:
    """Every ``stride``-th frame of ``trajectory``, starting with frame ``offset`` (< stride).

    Shapes: position (T, N, d) -> (ceil((T - offset) / stride), N, d); step_context likewise.
    A trajectory from a later offset is keyed ``"<key>+<offset>"``, so that errors name it.
    """
    if not 0 <= offset < stride:
        raise ValueError(f"offset {offset} must lie in [0, {stride}) for a frame stride of {stride}")
    context = None if trajectory.step_context is None else trajectory.step_context[offset::stride]
    key = trajectory.key if offset == 0 else f"{trajectory.key}+{offset}"
    return replace(trajectory, position=trajectory.position[offset::stride], step_context=context, key=key)


class StridedSplit(Split):
    """A split whose trajectories are strided on access (the underlying split stays lazy).

    With ``offsets`` k' > 1, stored trajectory i gives items i k' .. i k' + k' - 1, its
    offsets 0 .. k' - 1 (neighbours in the split: a window order that walks it visits
    each simulation's offsets together, and a process keeping recent trajectories
    reads each once).
    """

    def __init__(self, split: Sequence[Trajectory], stride: int, offsets: int = 1):
        if not 1 <= offsets <= stride:
            raise ValueError(f"offsets {offsets} must lie in [1, {stride}] for a frame stride of {stride}")
        self._split = split
        self._stride = stride
        self._offsets = offsets

    def __len__(self) -> int:
        return len(self._split) * self._offsets

    def _at(self, index: int) -> Trajectory:
        stored, offset = divmod(index, self._offsets)
        return strided(self._split[stored], self._stride, offset)

    def in_parts(self, index: int) -> Trajectory:
        """Trajectory ``index`` for processes that each read a run of its particles (``Trajectory.particles``)."""
        stored, offset = divmod(index, self._offsets)
        return strided(scene_in_parts(self._split, stored), self._stride, offset)


class FrameStrideDataset(Dataset):
    """``dataset`` with every ``stride``-th frame: ``dt`` is ``stride`` times the stored one.

    The metadata's velocity and acceleration statistics are those of the strided
    frames, computed on the train split (or, where a folder has none, the first
    split it holds); ``frame_stride`` records the stride applied.
    """

    def __init__(
        self, dataset: Dataset, stride: int, kinematic_types: Collection[int], all_offsets_in_train: bool = False
    ):
        """``kinematic_types``: the particle types the statistics leave out (kinematic materials).

        ``all_offsets_in_train``: the train split holds each trajectory at every offset
        (``stride`` trajectories per stored one); the other splits keep the first.
        """
        super().__init__(dataset.params, dataset.path, allow_pickle=dataset.allow_pickle)
        self.name = dataset.name  # type: ignore[misc]  # the wrapped layout's name, per instance (a ClassVar elsewhere)
        self.inner = dataset
        self.stride = stride
        self.train_offsets = stride if all_offsets_in_train else 1
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
        return StridedSplit(self.inner.split(name), self.stride, self.train_offsets if name == "train" else 1)

    def has_split(self, name: str) -> bool:
        return self.inner.has_split(name)
