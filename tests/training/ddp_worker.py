"""One rank of a 2-process CPU training: started by torch.multiprocessing (train_rank) or by torchrun (run as a
script)."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import torch

from gns_framework.config.recipe import validate_recipe
from gns_framework.errors import DatasetError, GnsError
from gns_framework.plugins import load_registry
from gns_framework.training import distributed
from gns_framework.training.distributed import Processes, processes_from_environment
from gns_framework.training.trainer import Trainer


def train_rank(
    rank: int, world_size: int, port: int, recipe: dict, run_dir: str, snapshots: list[int], out: str
) -> None:
    """Train to each step of ``snapshots`` in turn, saving this rank's parameters and losses at each."""
    os.environ.update({"MASTER_ADDR": "127.0.0.1", "MASTER_PORT": str(port), "GLOO_SOCKET_IFNAME": "lo"})
    torch.set_num_threads(1)
    registry = load_registry()
    trainer = Trainer(
        validate_recipe(recipe, registry),
        registry,
        run_dir=run_dir,
        processes=Processes(rank, world_size, rank),
        progress=False,
    )
    try:
        for steps in snapshots:
            losses = trainer.train(steps)
            snapshot = {
                "params": trainer.simulator.state_dict(),
                "losses": losses,
                "windows": trainer.order.draw(0).mine,
                "validation": trainer.last_validation,
            }
            torch.save(snapshot, Path(out) / f"rank{rank}-step{steps}.pt")
        trainer.close()
    finally:
        distributed.stop()


def train_under_torchrun(recipe_file: str, out: str, steps: int) -> None:
    """One torchrun worker: train ``steps`` steps, then save this rank's parameters and gradients.

    The gradients are those of the last step after DDP averaged them, so they must be
    equal on every rank, and present for every parameter (DDP stops a run at the next
    step when a parameter gets none).
    """
    processes = processes_from_environment()
    registry = load_registry()
    recipe = validate_recipe(json.loads(Path(recipe_file).read_text()), registry)
    trainer = Trainer(recipe, registry, run_dir=Path(out) / "run", processes=processes, progress=False)
    try:
        losses = trainer.train(steps)
        named = dict(trainer.simulator.named_parameters())
        snapshot = {
            "params": {name: p.detach() for name, p in named.items()},
            "grads": {name: p.grad for name, p in named.items()},
            "losses": losses,
        }
        torch.save(snapshot, Path(out) / f"rank{processes.rank}.pt")
        trainer.close()
    finally:
        distributed.stop()


def share_from_chief(rank: int, world_size: int, port: int, out: str) -> None:
    """Rank 0's result of ``from_chief`` on every rank, then rank 0's failure raised on every rank; written to
    ``out``."""
    os.environ.update({"MASTER_ADDR": "127.0.0.1", "MASTER_PORT": str(port), "GLOO_SOCKET_IFNAME": "lo"})
    processes = Processes(rank, world_size, rank)
    distributed.start(processes, torch.device("cpu"))
    computed: list[int] = []

    def compute() -> dict:
        computed.append(rank)
        return {"statistics": [0.5, float(rank)]}

    def fail() -> dict:
        raise DatasetError("data/train.npz: trajectory 'a': position: non-finite value at frame 3, particle 1")

    try:
        shared = distributed.from_chief(processes, compute)
        try:
            distributed.from_chief(processes, fail)
            failure = "none"
        except GnsError as exc:
            failure = f"{type(exc).__name__}: {exc}"
        Path(out, f"rank{rank}.json").write_text(
            json.dumps({"shared": shared, "computed": computed, "failure": failure})
        )
    finally:
        distributed.stop()


if __name__ == "__main__":
    train_under_torchrun(sys.argv[1], sys.argv[2], int(sys.argv[3]))
