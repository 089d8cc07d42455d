"""``gns demo``: a pretrained learned simulator on sand collapses it has never seen, and training from scratch.

Everything runs locally with no network:

1. the MLS-MPM ground-truth simulator generates granular column collapses of the
   demo scene: a small training set (scene seed) and held-out collapses drawn
   with another seed, so no held-out collapse was seen in training (both cached
   in the output folder after the first run);
2. a short model is trained from scratch on the training set, to show the
   training pipeline;
3. the shipped pretrained model (``models/sand2d_fast.pt``, trained by
   ``gns train`` on the same scene family; ``models/README.md`` says how) and the
   short model roll out the held-out collapses; the first is animated against
   the ground truth;
4. the error-against-run-time report compares both with the simulator at the
   data's grid and at half of it.

Held-out data outside the pretrained model's training envelope (another
``--scene``, say) is refused unless ``--outside-envelope``; the short model's
narrow envelope (a few collapses) is only reported, in the report's warning.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import torch

from ..assembly.data import open_dataset
from ..assembly.ground_truth import build_ground_truth_simulator
from ..assembly.trained import LoadedModel, load_trained
from ..config.recipe import load_recipe
from ..errors import GnsError
from ..ground_truth.generate import generate_dataset, is_up_to_date, provenance
from ..ground_truth.scene_spec import load_scene
from ..io.rollout_file import write_rollout
from ..model.rollout import rollout
from ..plugins import load_registry
from ..training.trainer import Trainer
from .arguments import non_negative_int, positive_int
from .envelope_option import add_outside_envelope, enforce_envelope
from .progress import report_progress

REPO = Path(__file__).resolve().parents[2]
TRAINING_COUNTS = {"train": 10, "valid": 1, "test": 1}
HELD_OUT_SEED = 2
"""Scene seed of the held-out collapses: the shipped model trained on seed 0 and was evaluated on seed 1."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, default=Path("runs/demo"), help="demo folder (default runs/demo)")
    parser.add_argument(
        "--steps", type=positive_int, default=1000, help="training steps of the short model (default 1000)"
    )
    parser.add_argument(
        "--scene", type=Path, default=REPO / "scenes" / "demo_sand_2d.yaml", help="scene spec to simulate"
    )
    parser.add_argument(
        "--recipe",
        type=Path,
        default=REPO / "recipes" / "sand2d_fast.yaml",
        help="recipe of the short model trained here",
    )
    parser.add_argument(
        "--model",
        type=Path,
        default=REPO / "models" / "sand2d_fast.pt",
        help="pretrained checkpoint rolled out on the held-out collapses (default models/sand2d_fast.pt)",
    )
    parser.add_argument("--held-out", type=positive_int, default=3, help="held-out collapses to simulate (default 3)")
    parser.add_argument(
        "--held-out-seed",
        type=non_negative_int,
        default=HELD_OUT_SEED,
        help=f"scene seed of the held-out collapses (default {HELD_OUT_SEED}; the shipped model trained on seed 0)",
    )
    parser.add_argument(
        "--repeats", type=positive_int, default=3, help="timed rollouts per model in the report (default 3)"
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")
    add_outside_envelope(parser)


def _simulate(scene, simulator, folder: Path, counts: dict[str, int], registry, progress: bool) -> None:
    if is_up_to_date(folder, provenance(scene, simulator, counts)):
        print(f"using the cached dataset {folder}")
        return
    print(
        f"simulating {sum(counts.values())} trajectories of {scene.name} (seed {scene.seed}) with {simulator.name} "
        f"into {folder} ..."
    )
    generate_dataset(scene, simulator, folder, registry.get("dataset", "safe"), counts, progress)


def run(args: argparse.Namespace) -> int:
    registry = load_registry()
    progress = not args.no_progress
    if not args.model.is_file():
        raise GnsError(
            f"{args.model}: pretrained model not found (--model; the repository ships models/sand2d_fast.pt)"
        )
    scene = load_scene(args.scene)
    simulator = build_ground_truth_simulator(scene, registry, args.scene)
    data, held_out = args.out / "data", args.out / "held_out"
    _simulate(scene, simulator, data, TRAINING_COUNTS, registry, progress)
    unseen = scene.model_copy(update={"seed": args.held_out_seed})
    # One training trajectory is the least a dataset holds; the held-out collapses are its test split.
    _simulate(unseen, simulator, held_out, {"train": 1, "valid": 0, "test": args.held_out}, registry, progress)

    recipe = load_recipe(
        args.recipe, registry, {"training": {"steps": args.steps, "validate_every": max(args.steps // 5, 1)}}
    )
    trainer = Trainer(recipe, registry, run_dir=args.out / "run", dataset_path=data, progress=progress)
    try:
        trainer.checkpoints.resume()
        before = trainer.validate()
        trainer.train()
        after = trainer.validate()
    finally:
        trainer.close()
    print(
        f"short model: validation one-step loss {before['valid_one_step_loss']:.4g} -> "
        f"{after['valid_one_step_loss']:.4g}"
    )
    best = trainer.run.best_checkpoint
    saved = best if best.is_file() else trainer.checkpoints.save()
    assert saved is not None  # one process: rank 0 writes it
    short = load_trained(saved, registry)
    pretrained = load_trained(args.model, registry)
    print(f"pretrained model: {args.model} (step {pretrained.step})")

    models = [(pretrained.recipe.name + "-pretrained", pretrained), (f"{recipe.name}-{args.steps}-steps", short)]
    for number, group in enumerate(_by_data_view(models)):
        _roll_out_and_report(group, held_out, args.out, number, registry, args.repeats, progress, args.outside_envelope)
    return 0


def _by_data_view(models: list[tuple[str, LoadedModel]]) -> list[list[tuple[str, LoadedModel]]]:
    """Models grouped by how they see the data (frame stride, history): one report compares a group."""
    groups: dict[tuple, list] = {}
    for name, model in models:
        groups.setdefault((model.recipe.dataset.frame_stride, model.simulator.setup.history), []).append((name, model))
    return list(groups.values())


def _roll_out_and_report(
    models, held_out: Path, out: Path, number: int, registry, repeats: int, progress: bool, outside: bool
) -> None:
    from ..evaluation.candidates import cases_from_split, compare
    from ..evaluation.report import write_report
    from ..io.rollout_file import load_rollout
    from ..viz.animation import animate_rollout

    name, first = models[0]
    dataset = open_dataset(first.recipe.dataset, registry, held_out)
    test = dataset.split("test")
    warnings = []
    for _, model in models:
        # The model trained here on a few collapses shows the pipeline: its narrow envelope is reported,
        # not enforced. The pretrained model is refused outside its own unless --outside-envelope.
        allowed = outside or model.path.resolve().is_relative_to(out.resolve())
        warnings += enforce_envelope(model, dataset.metadata(), list(test), allowed, f"{held_out} (split test)", "demo")
    if number == 0:
        guard = first.rollout_guard()
        result = rollout(first.simulator, test[0], progress=progress, guard=guard)
        metadata = dataset.metadata()
        if warnings:
            metadata = metadata.model_copy(update={"outside_envelope": warnings})
        path = write_rollout(out / "rollout_held_out_0000.npz", result, metadata)
        print(f"{name}: rollout of {result.num_steps} steps of a held-out collapse written to {path}")
        saved = load_rollout(path)
        names = registry.material_names(saved.particle_type)
        gif = animate_rollout(saved, out / "rollout.gif", every=1, material_names=names)
        print(f"animation (prediction | ground truth): {gif}")
    cases = cases_from_split(test)
    with report_progress(not progress) as bar:
        report = compare(
            models, cases, dataset.metadata(), registry, torch.device("cpu"), repeats=repeats, progress=bar
        )
    report = dataclasses.replace(report, warnings=tuple(warnings))
    paths = write_report(report, out / ("report" if number == 0 else f"report_{number + 1}"))
    print(paths["markdown"].read_text())
    print(f"error against run time: {paths['error_vs_time']}")
