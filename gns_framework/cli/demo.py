"""``gns demo``: simulate a small sand dataset, train the reference recipe briefly, roll out, report.

Everything runs locally with no network: the MLS-MPM ground-truth simulator
generates granular column collapses (cached in the output folder after the
first run), the reference GNS learns them, the test collapse is rolled out and
animated, and the error-against-run-time report compares it with the simulator.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from ..checkpoint import list_checkpoints
from ..loading import load_trained
from ..plugins import load_registry
from ..recipe import load_recipe
from ..rollout import rollout, write_rollout
from ..rollout_guard import RolloutGuard
from ..simulation.build import build_simulator
from ..simulation.generate import generate_dataset, is_up_to_date, provenance
from ..simulation.scene_spec import load_scene
from ..training.trainer import Trainer
from .arguments import positive_int

REPO = Path(__file__).resolve().parents[2]
COUNTS = {"train": 10, "valid": 1, "test": 1}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, default=Path("runs/demo"), help="demo folder (default runs/demo)")
    parser.add_argument("--steps", type=positive_int, default=1500, help="training steps (default 1500)")
    parser.add_argument("--scene", type=Path, default=REPO / "scenes" / "demo_sand_2d.yaml", help="scene spec to simulate")
    parser.add_argument("--recipe", type=Path, default=REPO / "recipes" / "sand2d.yaml", help="recipe to train")
    parser.add_argument("--repeats", type=positive_int, default=3, help="timed rollouts per model in the report (default 3)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")


def run(args: argparse.Namespace) -> int:
    registry = load_registry()
    progress = not args.no_progress
    data = args.out / "data"
    scene = load_scene(args.scene)
    simulator = build_simulator(scene, registry, args.scene)
    if is_up_to_date(data, provenance(scene, simulator, COUNTS)):
        print(f"using the cached dataset {data}")
    else:
        print(f"simulating {sum(COUNTS.values())} trajectories of {scene.name} with {simulator.name} into {data} ...")
        generate_dataset(scene, simulator, data, registry.get("dataset", "safe"), COUNTS, progress)

    recipe = load_recipe(args.recipe, registry, {"training": {"steps": args.steps, "validate_every": max(args.steps // 5, 1)}})
    trainer = Trainer(recipe, registry, run_dir=args.out / "run", dataset_path=data, progress=progress)
    try:
        trainer.resume()
        before = trainer.validate()
        trainer.train()
        after = trainer.validate()
    finally:
        trainer.close()
    print(f"validation one-step loss: {before['valid_one_step_loss']:.4g} -> {after['valid_one_step_loss']:.4g}")

    loaded = load_trained(list_checkpoints(trainer.checkpoint_dir)[-1][1], registry)
    test = trainer.data.dataset.split("test")
    guard = RolloutGuard.from_spec(loaded.simulator.scene, loaded.recipe.rollout.guard)
    result = rollout(loaded.simulator, test[0], progress=progress, guard=guard)
    path = write_rollout(args.out / "rollout_test_0000.npz", result, loaded.metadata)
    print(f"rollout of {result.predicted.shape[0]} steps written to {path}; position MSE {result.position_mse:.4g}")
    from ..evaluation.candidates import cases_from_split, compare
    from ..evaluation.report import write_report
    from ..evaluation.rollout_file import load_rollout
    from ..viz.animation import animate_rollout

    gif = animate_rollout(load_rollout(path), args.out / "rollout.gif", every=2)
    print(f"animation (prediction | ground truth): {gif}")
    cases = cases_from_split(test, loaded.metadata, loaded.simulator.scene.history)
    report = compare([(recipe.name, loaded)], cases, loaded.metadata, registry, torch.device("cpu"), repeats=args.repeats)
    paths = write_report(report, args.out / "report")
    print(paths["markdown"].read_text())
    print(f"error against run time: {paths['error_vs_time']}")
    return 0
