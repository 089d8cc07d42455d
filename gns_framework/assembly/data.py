"""Opening a recipe's dataset and deriving the scene it gives: shared by training, rollout, evaluation and inversion."""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from ..config.recipe import DatasetSpec, Recipe
from ..contracts import Dataset, ModelSetup
from ..data.metadata import DatasetMetadata
from ..data.mirror import MirroredDataset
from ..data.pickle_grant import pickle_granted
from ..data.stride import FrameStrideDataset
from ..data.trajectory import Trajectory
from ..errors import DatasetError
from ..moved import renamed_attribute
from ..plugins import Registry
from .scene import scene_from_data


def open_dataset(
    spec: DatasetSpec,
    registry: Registry,
    path: str | Path | None = None,
    allow_pickle: Path | None = None,
    keep: int | None = None,
) -> Dataset:
    """The dataset plugin a recipe names, on ``path`` (default: the recipe's), seen every ``frame_stride`` frames.

    ``allow_pickle`` is the folder the user's ``--allow-pickle`` names: it lets the
    plugin unpickle anything only if it is this dataset's folder. ``keep``: how many
    trajectories each split keeps in memory (:func:`~gns_framework.data.memory.trajectories_kept`;
    None: all).
    """
    cls, params = registry.resolve("dataset", spec, ("dataset",))
    folder = Path(path if path is not None else spec.path)
    if not folder.is_dir():
        raise DatasetError(f"{folder}: dataset folder not found (dataset.path in the recipe, or --dataset)")
    dataset = cls(params, folder, allow_pickle=pickle_granted(folder, allow_pickle))
    dataset.keep_trajectories = keep
    if spec.frame_stride > 1:
        dataset = FrameStrideDataset(
            dataset, spec.frame_stride, registry.kinematic_types(), all_offsets_in_train=spec.stride_offsets == "all"
        )
    if spec.mirror_axes:
        dataset = MirroredDataset(dataset, spec.mirror_axes, registry.kinematic_types())
    return dataset


@dataclass
class PreparedData:
    dataset: Dataset
    metadata: DatasetMetadata
    train: Sequence[Trajectory]
    valid: Sequence[Trajectory] | None
    setup: ModelSetup
    scene = renamed_attribute("scene", "setup")  # its name until 0.2


def prepare_data(
    recipe: Recipe,
    registry: Registry,
    allow_pickle: Path | None = None,
    keep: int | None = None,
    known: tuple[DatasetMetadata, ModelSetup] | None = None,
) -> PreparedData:
    """The recipe's dataset (at ``dataset.path``), its train and valid splits and the model setup they give.

    ``keep``: trajectories each split keeps in memory (None: all). ``known``: the
    metadata (with its statistics) and setup another process already derived from
    the same data; given, nothing is read here but the splits' lists of trajectories.
    """
    dataset = open_dataset(recipe.dataset, registry, allow_pickle=allow_pickle, keep=keep)
    metadata = dataset.metadata() if known is None else known[0]
    train = dataset.split("train")
    valid = dataset.split("valid") if dataset.has_split("valid") else None
    if known is not None:
        return PreparedData(dataset, metadata, train, valid, known[1])
    seen = itertools.chain(train, valid if valid is not None else ())
    setup = scene_from_data(metadata, seen, recipe.model, registry, source=str(dataset.path))
    return PreparedData(dataset, metadata, train, valid, setup)
