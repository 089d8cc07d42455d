"""dataset.memory: a training process keeps a few trajectories and trains bitwise as one that keeps them all."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from tiny import tiny_recipe_mapping

from gns_framework.config.recipe import validate_recipe
from gns_framework.data.memory import TRAJECTORIES_KEPT, trajectories_kept
from gns_framework.plugins import load_registry
from gns_framework.training.trainer import Trainer


@pytest.mark.parametrize(
    ("memory", "processes", "kept"),
    [("all", 1, None), ("all", 4, None), ("auto", 1, None), ("auto", 2, TRAJECTORIES_KEPT), ("windows", 1, 8)],
)
def test_auto_keeps_everything_for_one_process_and_a_few_trajectories_for_several(memory, processes, kept):
    assert trajectories_kept(memory, processes) == kept


def _mapped(array: np.ndarray) -> bool:
    """Whether ``array`` is a view of a file's memory map (validation and striding make plain views of it)."""
    while array is not None and not isinstance(array, np.memmap):
        array = array.base
    return array is not None


def _trained(dataset, tmp_path, memory: str, frame_stride: int) -> Trainer:
    raw = tiny_recipe_mapping(dataset)
    raw["dataset"].update(memory=memory, frame_stride=frame_stride)
    raw["training"].update(steps=6, batch_size=3)
    registry = load_registry()
    trainer = Trainer(validate_recipe(raw, registry), registry, run_dir=tmp_path / memory, progress=False)
    trainer.train(6)
    trainer.close()
    return trainer


@pytest.mark.parametrize("frame_stride", [1, 2])
def test_training_that_keeps_a_few_memory_mapped_trajectories_is_bitwise_the_same(tmp_path, frame_stride, monkeypatch):
    from synthetic import write_synthetic_dataset

    monkeypatch.setattr("gns_framework.data.memory.TRAJECTORIES_KEPT", 2)  # fewer than the 5 trajectories
    dataset = write_synthetic_dataset(tmp_path / "data", train=5, valid=1, test=1, frames=16)
    whole = _trained(dataset, tmp_path, "all", frame_stride)
    windows = _trained(dataset, tmp_path, "windows", frame_stride)

    assert windows.data.metadata == whole.data.metadata
    train = windows.data.train
    first = train[0]
    # The safe layout's positions are stored uncompressed, so a window's frames come from the file's map.
    assert _mapped(first.position) and not _mapped(whole.data.train[0].position)
    for name, value in whole.simulator.state_dict().items():
        assert torch.equal(value, windows.simulator.state_dict()[name]), f"{name} differs with memory: windows"
