"""Rollout error against training wall-clock time: the reference recipe and the project's best, side by side.

Usage:
    python benchmarks/time_to_accuracy.py --budget-minutes M --data DIR --threads T [--json]
        [--held-out DIR] [--seeds S] [--reference recipes/sand2d.yaml] [--ours recipes/sand2d_fast_grid.yaml]
        [--points P] [--trajectories K]

Each recipe trains from scratch for M minutes of wall clock on the same dataset
and the same number of threads, once per seed (``--seeds``, recipe seeds 0..S-1),
one run after the other and alternating between the recipes (reference seed 0,
ours seed 0, reference seed 1, ...), so that load on a shared machine hits both
alike; never two at once (runs that share the cores slow each other down). At P
evenly spaced wall-clock points the clock stops, the model the recipe would ship
(its weight average when it keeps one, ``training.ema_decay``, else its weights)
rolls out the first K test trajectories of ``--held-out`` (default: the training
dataset's test split) from their first C frames, and three errors are recorded:
runout error (% of the true runout), final-cloud Sinkhorn distance (% of the domain
size) and position MSE over the whole rollout. Evaluation time is not training time.

Reported per recipe and time point: the mean and the spread (lowest, highest) over
the seeds; per seed, whether the rollout error was steady (after the first third of
the budget, no runout error above twice the best so far); and the ratio reference /
ours of the late medians, per seed pairing and as the median with its spread.

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
from gns_framework.plugins import load_registry
from gns_framework.training.tracking import TrackerGroup
from gns_framework.training.trainer import Trainer
from gns_framework.training.validation import rollout_score_summary

REPO = Path(__file__).resolve().parents[1]
METRICS = {
    "runout_error_pct": "valid_rollout_runout_error_pct",
    "sinkhorn_pct": "valid_rollout_sinkhorn_pct",
    "position_mse": "valid_rollout_mse",
}
"""Reported name -> tracked validation name (:meth:`gns_framework.plugins.Registry.validation_metrics`)."""
CALIBRATION_STEPS = 20


def _overrides(threads: int, steps: int | None = None) -> dict:
    training = {
        "threads": threads,
        "device": "cpu",
        "validate_every": 10**9,
        "checkpoint_every": 10**9,
        "log_every": 10**9,
    }
    if steps is not None:
        training["steps"] = steps
    return {"training": training}


def _trainer(
    recipe_path: Path, data: Path, threads: int, run_dir: Path, steps: int | None = None, seed: int = 0
) -> Trainer:
    registry = load_registry()
    recipe = load_recipe(recipe_path, registry, {**_overrides(threads, steps), "seed": seed})
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


def run_recipe(
    recipe_path: Path,
    data: Path,
    threads: int,
    minutes: float,
    points: int,
    trajectories: int,
    seed: int = 0,
    held_out: Path | None = None,
) -> dict:
    with tempfile.TemporaryDirectory() as scratch:
        scratch = Path(scratch)
        steps = _step_budget(recipe_path, data, threads, minutes, scratch)
        trainer = _trainer(recipe_path, data, threads, scratch / "run", steps=steps if steps else 10**9, seed=seed)
        if held_out is None:
            test = trainer.data.dataset.split("test")
        else:
            from gns_framework.assembly.data import open_dataset

            test = open_dataset(trainer.recipe.dataset, trainer.registry, held_out).split("test")
        cases = [test[i] for i in range(min(trajectories, len(test)))]
        marks = [minutes * 60 * (k + 1) / points for k in range(points)]
        trained, evaluations = 0.0, []
        trainer.simulator.train()
        for mark in marks:
            # Past its step budget a cosine schedule holds lr_min: a slow calibration never leaves time unused.
            while trained < mark:
                started = time.perf_counter()
                trainer.train_step()
                trained += time.perf_counter() - started
            # What the recipe would ship: the weight average when it keeps one.
            shipped = trainer.ema.module if trainer.ema is not None else trainer.simulator
            shipped.eval()
            scores = rollout_score_summary(shipped, cases, trainer.validation.score_rollout)
            trainer.simulator.train()
            point = {"minutes": trained / 60, "step": trainer.step}
            point.update({name: scores.get(key) for name, key in METRICS.items()})
            evaluations.append(point)
            print(
                f"  {trainer.recipe.name}: {point['minutes']:6.2f} min, step {point['step']:6d}: "
                + ", ".join(f"{name} {point[name]:.4g}" for name in METRICS if point[name] is not None),
                flush=True,
            )
        return {
            "recipe": str(recipe_path),
            "name": trainer.recipe.name,
            "seed": seed,
            "steps": trainer.step,
            "evaluations": evaluations,
            "steady": steady(evaluations, minutes),
        }


def steady(evaluations: list[dict], minutes: float, metric: str = "runout_error_pct") -> bool | None:
    """Whether, after the first third of the budget, no evaluation's ``metric`` exceeds twice the best so far."""
    best, ok = None, True
    for point in evaluations:
        value = point[metric]
        if value is None:
            return None
        if best is not None and point["minutes"] > minutes / 3 and value > 2 * best:
            ok = False
        best = value if best is None else min(best, value)
    return ok


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


def _spread(values: list[float]) -> dict | None:
    """mean, median, lowest and highest of ``values`` (None when empty)."""
    if not values:
        return None
    return {
        "mean": statistics.fmean(values),
        "median": statistics.median(values),
        "low": min(values),
        "high": max(values),
    }


def spread_per_point(seeded: list[dict]) -> list[dict]:
    """Per evaluation point: minutes (mean over seeds) and each metric's spread over the seeds."""
    points = []
    for k in range(min(len(run["evaluations"]) for run in seeded)):
        at = [run["evaluations"][k] for run in seeded]
        point = {"minutes": statistics.fmean(p["minutes"] for p in at)}
        point.update({name: _spread([p[name] for p in at if p[name] is not None]) for name in METRICS})
        points.append(point)
    return points


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--budget-minutes", type=float, required=True, help="training wall clock per recipe")
    parser.add_argument("--data", type=Path, required=True, help="dataset folder (train and test splits)")
    parser.add_argument("--threads", type=int, required=True, help="torch intra-op threads for both recipes")
    parser.add_argument("--json", action="store_true", help="last line: the figures as one JSON object")
    parser.add_argument("--reference", type=Path, default=REPO / "recipes" / "sand2d.yaml")
    parser.add_argument(
        "--ours",
        type=Path,
        default=REPO / "recipes" / "sand2d_fast_grid.yaml",
        help="the project's best recipe (default: the grid-processor recipe)",
    )
    parser.add_argument("--points", type=int, default=5, help="evaluations per run (evenly spaced in wall clock)")
    parser.add_argument("--trajectories", type=int, default=20, help="test trajectories rolled out per evaluation")
    parser.add_argument("--held-out", type=Path, help="dataset whose test split is rolled out (default: --data's)")
    parser.add_argument(
        "--seeds", type=int, default=3, help="runs per recipe, recipe seeds 0..S-1, alternating recipes"
    )
    parser.add_argument(
        "--late",
        type=int,
        default=3,
        help="evaluations at the end whose median gives the steadier ratio (all of them if fewer)",
    )
    args = parser.parse_args(argv)
    if args.late < 1:
        parser.error(f"--late must be at least 1, got {args.late}")
    args.late = min(args.late, args.points)
    torch.set_num_threads(args.threads)

    runs: dict[str, list[dict]] = {"reference": [], "ours": []}
    for seed in range(args.seeds):
        for role, path in (("reference", args.reference), ("ours", args.ours)):
            print(f"{role}: {path}, seed {seed}, {args.budget_minutes} min on {args.threads} thread(s)", flush=True)
            runs[role].append(
                run_recipe(
                    path,
                    args.data,
                    args.threads,
                    args.budget_minutes,
                    args.points,
                    args.trajectories,
                    seed,
                    args.held_out,
                )
            )
    summary = {role: spread_per_point(seeded) for role, seeded in runs.items()}
    for role, points in summary.items():
        print(f"\n{role} ({runs[role][0]['name']}), mean [lowest, highest] over {args.seeds} seed(s):")
        for point in points:
            print(
                f"  {point['minutes']:6.2f} min: "
                + ", ".join(
                    f"{name} {point[name]['mean']:.4g} [{point[name]['low']:.4g}, {point[name]['high']:.4g}]"
                    for name in METRICS
                    if point[name] is not None
                )
            )
        print(
            f"  steady (no runout error above 2x the best so far after a third of the budget): "
            f"{[run['steady'] for run in runs[role]]}"
        )
    per_seed = [
        _ratios(
            {
                "reference": _late_medians(ref["evaluations"][-args.late :]),
                "ours": _late_medians(ours["evaluations"][-args.late :]),
            }
        )
        for ref, ours in zip(runs["reference"], runs["ours"], strict=True)
    ]
    late_ratio = {name: _spread([r[name] for r in per_seed if r[name] is not None]) for name in METRICS}
    print(
        f"\nreference / ours, median of the last {args.late} evaluations, per seed: "
        + "; ".join(", ".join(f"{n} {r[n]:.2f}" for n in METRICS if r[n] is not None) for r in per_seed)
    )
    print(
        "over the seeds: "
        + ", ".join(
            f"{name} {v['median']:.2f} [{v['low']:.2f}, {v['high']:.2f}]"
            for name, v in late_ratio.items()
            if v is not None
        )
    )
    if args.json:
        print(
            json.dumps(
                {
                    "budget_minutes": args.budget_minutes,
                    "threads": args.threads,
                    "data": str(args.data),
                    "held_out": str(args.held_out) if args.held_out else None,
                    "seeds": args.seeds,
                    "runs": runs,
                    "per_point": summary,
                    "late": args.late,
                    "ratio_reference_over_ours_late_median_per_seed": per_seed,
                    "ratio_reference_over_ours_late_median": late_ratio,
                }
            )
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
