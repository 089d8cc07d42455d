"""``gns demo``: generate a small dataset, train the reference recipe briefly, roll out and render.

Runs on the embedded default scene (soft spheres falling in a box, simulated
in-process), with no network. The dataset is cached in the output folder.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..checkpoint import list_checkpoints
from ..data.metadata import load_metadata
from ..demo.soft_spheres import write_synthetic_dataset
from ..errors import DatasetError
from ..loading import load_trained
from ..plugins import load_registry
from ..recipe import load_recipe
from ..rollout import rollout, write_rollout
from ..rollout_guard import RolloutGuard
from ..training.trainer import Trainer
from .arguments import positive_int

RECIPE = Path(__file__).resolve().parents[2] / "recipes" / "water2d.yaml"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, default=Path("runs/demo"), help="demo folder (default runs/demo)")
    parser.add_argument("--steps", type=positive_int, default=1000, help="training steps (default 1000)")
    parser.add_argument("--recipe", type=Path, default=RECIPE, help="recipe to train (default recipes/water2d.yaml)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")


def run(args: argparse.Namespace) -> int:
    registry = load_registry()
    data = args.out / "data"
    try:
        load_metadata(data)
        print(f"using cached dataset {data}")
    except DatasetError:
        print(f"generating the demo dataset in {data} ...")
        write_synthetic_dataset(data, train=8, valid=2, test=1, frames=60)
    recipe = load_recipe(args.recipe, registry, {"training": {"steps": args.steps, "validate_every": max(args.steps // 4, 1)}})
    trainer = Trainer(recipe, registry, run_dir=args.out / "run", dataset_path=data, progress=not args.no_progress)
    try:
        trainer.resume()
        before = trainer.validate()
        trainer.train()
        after = trainer.validate()
    finally:
        trainer.close()
    print(f"validation one-step loss: {before['valid_one_step_loss']:.4g} -> {after['valid_one_step_loss']:.4g}")
    loaded = load_trained(list_checkpoints(trainer.checkpoint_dir)[-1][1], registry)
    trajectory = trainer.data.dataset.split("test")[0]
    guard = RolloutGuard.from_spec(loaded.simulator.scene, loaded.recipe.rollout.guard)
    result = rollout(loaded.simulator, trajectory, progress=not args.no_progress, guard=guard)
    path = write_rollout(args.out / "rollout_test_0000.npz", result, loaded.metadata)
    print(f"rollout of {result.predicted.shape[0]} steps written to {path}; position MSE {result.position_mse:.4g}")
    from ..evaluation.rollout_file import load_rollout
    from ..viz.animation import animate_rollout

    print(f"animation (prediction | ground truth): {animate_rollout(load_rollout(path), args.out / 'rollout.gif', every=2)}")
    return 0
