"""``gns train``: train a learned simulator from a recipe (resumable)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..plugins import load_registry
from ..recipe import load_recipe
from ..training.trainer import Trainer
from .arguments import positive_int


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recipe", type=Path, help="recipe YAML file")
    parser.add_argument("--steps", type=positive_int, help="total training steps (overrides training.steps)")
    parser.add_argument("--dataset", type=Path, help="dataset folder (overrides dataset.path)")
    parser.add_argument("--out", type=Path, help="run folder (overrides output_dir; default runs/<name>)")
    parser.add_argument(
        "--resume",
        nargs="?",
        const="auto",
        metavar="CHECKPOINT",
        help="continue from CHECKPOINT, or with no value from the newest good checkpoint of the run folder",
    )
    parser.add_argument("--device", help="cpu, cuda or cuda:N (overrides training.device)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    registry = load_registry()
    overrides: dict = {}
    if args.steps is not None:
        overrides.setdefault("training", {})["steps"] = args.steps
    if args.device is not None:
        overrides.setdefault("training", {})["device"] = args.device
    recipe = load_recipe(args.recipe, registry, overrides)
    trainer = Trainer(recipe, registry, run_dir=args.out, dataset_path=args.dataset, progress=not args.no_progress)
    try:
        if args.resume is not None:
            resumed = trainer.resume(None if args.resume == "auto" else args.resume)
            print(f"resumed from {resumed} at step {trainer.step}" if resumed else "no checkpoint to resume from; starting at step 0")
        trainer.train()
        final = trainer.validate()
    finally:
        trainer.close()
    summary = ", ".join(f"{k} {v:.4g}" for k, v in final.items())
    print(f"trained {recipe.name} to step {trainer.step}; {summary}; checkpoints in {trainer.checkpoint_dir}")
    return 0
