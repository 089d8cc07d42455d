"""One rank of a 2-process CPU training, started by torch.multiprocessing from the DDP tests."""

from __future__ import annotations

import os
from pathlib import Path

import torch

from gns_framework.plugins import load_registry
from gns_framework.recipe import validate_recipe
from gns_framework.training import distributed
from gns_framework.training.distributed import Processes
from gns_framework.training.trainer import Trainer


def train_rank(rank: int, world_size: int, port: int, recipe: dict, run_dir: str, snapshots: list[int], out: str) -> None:
    """Train to each step of ``snapshots`` in turn, saving this rank's parameters and losses at each."""
    os.environ.update({"MASTER_ADDR": "127.0.0.1", "MASTER_PORT": str(port), "GLOO_SOCKET_IFNAME": "lo"})
    torch.set_num_threads(1)
    registry = load_registry()
    trainer = Trainer(
        validate_recipe(recipe, registry), registry, run_dir=run_dir, processes=Processes(rank, world_size, rank),
        progress=False,
    )
    try:
        for steps in snapshots:
            losses = trainer.train(steps)
            snapshot = {"params": trainer.simulator.state_dict(), "losses": losses, "windows": trainer.order.indices(0)}
            torch.save(snapshot, Path(out) / f"rank{rank}-step{steps}.pt")
        trainer.close()
    finally:
        distributed.stop()
