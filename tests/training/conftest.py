"""Fixtures of the training tests."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from ddp_worker import train_rank
from spawned import free_loopback_port, run_processes
from training_support import tiny_recipe, write_uneven_dataset


@pytest.fixture(scope="session")
def uneven_dataset(tmp_path_factory) -> Path:
    return write_uneven_dataset(tmp_path_factory.mktemp("uneven") / "data")


DDP_SNAPSHOTS = (3, 40)
"""Steps at which the 2-process run saves each rank's parameters: a short one, and the elastic test's full run."""


@pytest.fixture(scope="session")
def ddp_recipe(uneven_dataset) -> dict:
    return tiny_recipe(uneven_dataset, name="ddp", steps=DDP_SNAPSHOTS[-1], checkpoint_every=4, validate_every=1000)


@pytest.fixture(scope="session")
def ddp_snapshots(ddp_recipe, tmp_path_factory) -> dict[tuple[int, int], dict]:
    """``(rank, step) -> {"params", "losses", "windows"}`` of an uninterrupted 2-process CPU run."""
    out = tmp_path_factory.mktemp("ddp")
    run_processes(train_rank, (2, free_loopback_port(), ddp_recipe, str(out / "run"), list(DDP_SNAPSHOTS), str(out)))
    return {
        (rank, step): torch.load(out / f"rank{rank}-step{step}.pt", weights_only=True)
        for rank in (0, 1)
        for step in DDP_SNAPSHOTS
    }
