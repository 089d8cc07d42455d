"""A dataset whose train split also holds each trajectory reflected across its box's mid-plane.

The physics of a box of sand or water under gravity does not change when the box is seen
in a mirror along a horizontal axis: x -> lo + hi - x for every particle, the two walls
across that axis swapped. A network does not know this by construction (a grid processor's
convolutions, an MLP on relative positions): trained on columns that happen to collapse
one way more often, it learns the two directions apart and may run one out further than
the other. Training on both images of every trajectory (``dataset.mirror_axes``) teaches the
symmetry from the same simulations; validation and rollouts see the data as stored.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import replace

import numpy as np

from ..contracts import Dataset
from ..errors import DatasetError
from .lazy import Split
from .metadata import DatasetMetadata, compute_statistics
from .trajectory import Trajectory


def reflected(position: np.ndarray, axis: int, bounds: np.ndarray) -> np.ndarray:
    """A copy of ``position`` with ``lo + hi - x`` along ``axis`` of ``bounds`` (its own inverse).

    Shapes: position (..., d) -> (..., d); bounds (d, 2).
    """
    lo, hi = float(bounds[axis][0]), float(bounds[axis][1])
    position = np.array(position, copy=True)
    position[..., axis] = (lo + hi) - position[..., axis]
    return position


def mirrored(trajectory: Trajectory, axis: int, bounds: np.ndarray) -> Trajectory:
    """``trajectory`` reflected across the mid-plane of ``bounds`` along ``axis``.

    Every particle (kinematic ones too) moves to ``lo + hi - x`` along ``axis``; the walls of
    the two faces across it trade places. The key gains ``"~mirror<axis>"``, so errors name it.

    Shapes: position (T, N, d) -> (T, N, d); bounds (d, 2); walls (2 d, 2) -> (2 d, 2).
    """
    if trajectory.step_context is not None:
        raise DatasetError(
            f"{trajectory.key}: dataset.mirror_axes: the trajectory has a step context (global features per step), "
            "which a mirror image might have to change too; leave mirror_axes empty for this data"
        )
    position = reflected(trajectory.position, axis, bounds)
    walls = trajectory.walls
    if walls is not None:
        walls = np.array(walls, copy=True)
        walls[[2 * axis, 2 * axis + 1]] = walls[[2 * axis + 1, 2 * axis]]
    return replace(trajectory, position=position, walls=walls, key=f"{trajectory.key}~mirror{axis}")


class MirroredSplit(Split):
    """A split holding, for stored trajectory i, items i 2^a .. i 2^a + 2^a - 1: it and its images in every
    combination of the ``a`` mirror axes (neighbours in the split, so a process keeping recent trajectories
    reads each stored one once). ``bounds``: the box of a trajectory that stores none (the dataset's)."""

    def __init__(self, split: Sequence[Trajectory], axes: Sequence[int], bounds: np.ndarray):
        self._split, self._axes, self._bounds = split, tuple(axes), bounds
        self._images = 2 ** len(self._axes)

    def __len__(self) -> int:
        return len(self._split) * self._images

    def _at(self, index: int) -> Trajectory:
        stored, image = divmod(index, self._images)
        trajectory = self._split[stored]
        bounds = np.asarray(trajectory.bounds if trajectory.bounds is not None else self._bounds)
        for bit, axis in enumerate(self._axes):
            if image >> bit & 1:
                trajectory = mirrored(trajectory, axis, bounds)
        return trajectory


class MirroredDataset(Dataset):
    """``dataset`` whose train split holds every trajectory and its mirror images along ``axes``.

    The metadata's statistics are those of the mirrored train split (a velocity mean along
    a mirror axis comes out near zero, as the symmetry says); the other splits are unchanged.
    """

    def __init__(self, dataset: Dataset, axes: Sequence[int], kinematic_types: Collection[int]):
        super().__init__(dataset.params, dataset.path, allow_pickle=dataset.allow_pickle)
        self.name = dataset.name  # type: ignore[misc]  # the wrapped layout's name, per instance (a ClassVar elsewhere)
        self.inner = dataset
        self.kinematic_types = tuple(kinematic_types)
        stored = dataset.metadata()
        # Which axis gravity acts along is the scene's, not the data's to say (the MPM's default is y, axis 1, in
        # 2D and 3D): a mirror along it would teach sand to fall up, so the recipe names the horizontal axes.
        if any(not 0 <= a < stored.dim for a in axes) or len(set(axes)) != len(axes):
            raise DatasetError(
                f"{dataset.path}: dataset.mirror_axes: expected distinct axes in [0, {stored.dim - 1}] of this "
                f"{stored.dim}D data, each horizontal (not the one gravity acts along), got {list(axes)}"
            )
        self.axes = tuple(axes)
        self._bounds = np.asarray(stored.bounds, dtype=np.float64)
        self._metadata: DatasetMetadata | None = None

    def metadata(self) -> DatasetMetadata:
        if self._metadata is None:
            stored = self.inner.metadata()
            statistics = (
                compute_statistics(self.split("train"), self.kinematic_types, f"{self.path} (split train, mirrored)")
                if self.inner.has_split("train")
                else {}
            )
            self._metadata = stored.model_copy(update=statistics)
        return self._metadata

    def split(self, name: str) -> Sequence[Trajectory]:
        split = self.inner.split(name)
        return MirroredSplit(split, self.axes, self._bounds) if name == "train" else split

    def has_split(self, name: str) -> bool:
        return self.inner.has_split(name)
