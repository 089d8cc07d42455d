"""Rollout error against training wall-clock time: the reference recipe and the project's best, side by side.

Usage:
    python benchmarks/time_to_accuracy.py --budget-minutes M --data DIR --threads T [--json]
        [--reference recipes/sand2d.yaml] [--ours recipes/sand2d_fast_pushforward.yaml] [--points P] [--trajectories K]

Each recipe trains from scratch for M minutes of wall clock on the same dataset
and the same number of threads, one after the other (never at once: runs that
share the cores slow each other down). At P evenly spaced wall-clock points the
clock stops, the current model rolls out the first K trajectories of the test
split from their first C frames, and three errors are recorded: runout error
(% of the true runout), final-cloud Sinkhorn distance (% of the domain size) and
position MSE over the whole rollout. Evaluation time is not training time.

A recipe with a schedule fitted to its step budget (``schedule: cosine``) needs
a step count: its step time is measured first on 20 throwaway steps, and
``training.steps`` is set so the schedule ends at the budget; if the steps turn
out faster, training goes on at ``lr_min`` until the budget is spent. The
reference recipe keeps its own (exponential, effectively flat) schedule.

The last line of output is one JSON object: per recipe, the evaluation points
(minutes, step, metrics), the final ratio reference / ours per metric (above 1:
ours is better), and the same ratio of the medians over the last L evaluations
(``--late``, default 3). One evaluation of a few rollouts swings a lot from one
point to the next (a model between two good states can be far off), so the
ratio of late medians is the steadier figure of the two.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import torch

from gns_framework.config.recipe import load_recipe
from gns_framework.evaluation.candidates import granular_particle_types
from gns_framework.plugins import load_registry
from gns_framework.training.rollout_validation import validation_rollout_metrics
from gns_framework.training.tracking import TrackerGroup
from gns_framework.training.trainer import Trainer

REPO = Path(__file__).resolve().parents[1]
METRICS = {
    "runout_error_pct": "valid_rollout_runout_error_pct",
    "sinkhorn_pct": "valid_rollout_sinkhorn_pct",
    "position_mse": "valid_rollout_mse",
}
"""Reported name -> key of :func:`validation_rollout_metrics`."""
CALIBRATION_STEPS = 20


def _overrides(threads: int, steps: int | None = None) -> dict:
    training = {"threads": threads, "device": "cpu", "validate_every": 10**9, "checkpoint_every": 10**9, "log_every": 10**9}
    if steps is not None:
        training["steps"] = steps
    return {"training": training}


def _trainer(recipe_path: Path, data: Path, threads: int, run_dir: Path, steps: int | None = None) -> Trainer:
    registry = load_registry()
    recipe = load_recipe(recipe_path, registry, _overrides(threads, steps))
    # An empty tracker group tracks nothing: the benchmark prints its figures.
    return Trainer(recipe, registry, run_dir=run_dir, dataset_path=data, progress=False, tracker=TrackerGroup([]))


def _step_budget(recipe_path: Path, data: Path, threads: int, minutes: float, scratch: Path) -> int | None:
    """Steps that fill ``minutes`` for a recipe whose schedule needs its length; None for the others."""
    registry = load_registry()
    recipe = load_recipe(recipe_path, registry)
    if recipe.training.optimizer.schedule != "cosine":
        return None
    trainer = _trainer(recipe_path, data, threads, scratch / "calibration", steps=CALIBRATION_STEPS)
    trainer.train_step()  # first step: allocations and kernel build
    started = time.perf_counter()
    for _ in range(CALIBRATION_STEPS - 1):
        trainer.train_step()
    seconds = (time.perf_counter() - started) / (CALIBRATION_STEPS - 1)
    return max(CALIBRATION_STEPS, int(minutes * 60 / seconds))


def run_recipe(recipe_path: Path, data: Path, threads: int, minutes: float, points: int, trajectories: int) -> dict:
    with tempfile.TemporaryDirectory() as scratch:
        scratch = Path(scratch)
        steps = _step_budget(recipe_path, data, threads, minutes, scratch)
        trainer = _trainer(recipe_path, data, threads, scratch / "run", steps=steps if steps else 10**9)
        test = trainer.data.dataset.split("test")
        cases = [test[i] for i in range(min(trajectories, len(test)))]
        granular = granular_particle_types(trainer.data.scene, trainer.registry)
        marks = [minutes * 60 * (k + 1) / points for k in range(points)]
        trained, evaluations = 0.0, []
        trainer.simulator.train()
        for mark in marks:
            # Past its step budget a cosine schedule holds lr_min: a slow calibration never leaves time unused.
            while trained < mark:
                started = time.perf_counter()
                trainer.train_step()
                trained += time.perf_counter() - started
            trainer.simulator.eval()
            scores = validation_rollout_metrics(trainer.simulator, cases, trainer.data.metadata, granular, trainer.device)
            trainer.simulator.train()
            point = {"minutes": trained / 60, "step": trainer.step}
            point.update({name: scores.get(key) for name, key in METRICS.items()})
            evaluations.append(point)
            print(f"  {trainer.recipe.name}: {point['minutes']:6.2f} min, step {point['step']:6d}: "
                  + ", ".join(f"{name} {point[name]:.4g}" for name in METRICS if point[name] is not None), flush=True)
        return {"recipe": str(recipe_path), "name": trainer.recipe.name, "steps": trainer.step, "evaluations": evaluations}


def _late_medians(evaluations: list[dict]) -> dict:
    """Per metric, the median over ``evaluations`` of the values that exist (None when none does)."""
    medians = {}
    for name in METRICS:
        values = [e[name] for e in evaluations if e[name] is not None]
        medians[name] = statistics.median(values) if values else None
    return medians


def _ratios(errors: dict[str, dict]) -> dict:
    """Reference / ours per metric (None where either is missing or ours is exactly 0)."""
    ratios = {}
    for name in METRICS:
        theirs, ours = errors["reference"][name], errors["ours"][name]
        ratios[name] = None if theirs is None or ours is None or ours == 0 else theirs / ours
    return ratios


def _print_table(title: str, errors: dict[str, dict], ratios: dict) -> None:
    print(f"\n{title:<17}" + "".join(f"{name:>20}" for name in METRICS))
    for role, values in errors.items():
        print(f"{role:<17}" + "".join(f"{values[n]:>20.4g}" if values[n] is not None else f"{'-':>20}" for n in METRICS))
    print(f"{'reference / ours':<17}" + "".join(f"{ratios[n]:>20.2f}" if ratios[n] is not None else f"{'-':>20}"
                                               for n in METRICS))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--budget-minutes", type=float, required=True, help="training wall clock per recipe")
    parser.add_argument("--data", type=Path, required=True, help="dataset folder (train and test splits)")
    parser.add_argument("--threads", type=int, required=True, help="torch intra-op threads for both recipes")
    parser.add_argument("--json", action="store_true", help="last line: the figures as one JSON object")
    parser.add_argument("--reference", type=Path, default=REPO / "recipes" / "sand2d.yaml")
    parser.add_argument("--ours", type=Path, default=REPO / "recipes" / "sand2d_fast_pushforward.yaml",
                        help="the project's best recipe (default: the fast recipe with push-forward)")
    parser.add_argument("--points", type=int, default=5, help="evaluations per run (evenly spaced in wall clock)")
    parser.add_argument("--trajectories", type=int, default=4, help="test trajectories rolled out per evaluation")
    parser.add_argument("--late", type=int, default=3,
                        help="evaluations at the end whose median gives the steadier ratio (all of them if fewer)")
    args = parser.parse_args(argv)
    if args.late < 1:
        parser.error(f"--late must be at least 1, got {args.late}")
    args.late = min(args.late, args.points)
    torch.set_num_threads(args.threads)

    runs = {}
    for role, path in (("reference", args.reference), ("ours", args.ours)):
        print(f"{role}: {path}, {args.budget_minutes} min on {args.threads} thread(s)", flush=True)
        runs[role] = run_recipe(path, args.data, args.threads, args.budget_minutes, args.points, args.trajectories)
    final = {role: run["evaluations"][-1] for role, run in runs.items()}
    late = {role: _late_medians(run["evaluations"][-args.late:]) for role, run in runs.items()}
    ratios, late_ratios = _ratios(final), _ratios(late)
    _print_table("final errors", final, ratios)
    _print_table(f"median of the last {args.late}", late, late_ratios)
    if args.json:
        print(json.dumps({"budget_minutes": args.budget_minutes, "threads": args.threads, "data": str(args.data),
                          "runs": runs, "ratio_reference_over_ours": ratios, "late": args.late,
                          "late_median": late, "ratio_reference_over_ours_late_median": late_ratios}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
