"""``gns rollout``: roll a trained simulator out on a dataset split and save it with the ground truth."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..loading import load_trained
from ..plugins import load_registry
from ..rollout import rollout, write_rollout
from ..training.setup import open_dataset
from ..training.trainer import resolve_device


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("checkpoint", type=Path, help="checkpoint file written by gns train")
    parser.add_argument("--dataset", type=Path, help="dataset folder (default: the one the model was trained on)")
    parser.add_argument("--split", help="split to roll out (default: the recipe's rollout.split)")
    parser.add_argument("--steps", type=int, help="steps per rollout (default: to the end of each trajectory)")
    parser.add_argument("--trajectories", type=int, help="how many trajectories (default: all)")
    parser.add_argument("--out", type=Path, help="output folder (default: <run>/rollouts)")
    parser.add_argument("--device", default="auto", help="auto, cpu, cuda or cuda:N")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    registry = load_registry()
    device = resolve_device(args.device)
    loaded = load_trained(args.checkpoint, registry, device)
    spec = loaded.recipe.rollout
    dataset = open_dataset(loaded.recipe.dataset, registry, args.dataset)
    split_name = args.split or spec.split
    trajectories = dataset.split(split_name)
    count = min(len(trajectories), args.trajectories or spec.trajectories or len(trajectories))
    out = args.out or args.checkpoint.parent.parent / "rollouts"
    for index in range(count):
        trajectory = trajectories[index]
        result = rollout(loaded.simulator, trajectory, args.steps or spec.steps, device, progress=not args.no_progress)
        path = write_rollout(out / f"{split_name}_{index:04d}.npz", result, loaded.metadata)
        print(f"{path}: {result.predicted.shape[0]} steps, position MSE {result.position_mse:.4g}")
    return 0
