"""What each swap changes, measured: one component replaced at a time, trained alike, judged on held-out scenes.

Usage:
    python benchmarks/swaps.py --data DIR --held-out DIR [--base recipes/sizes/sand2d_fast_3x32.yaml]
        [--steps 1500] [--seeds 0] [--cases 10] [--threads 1] [--swaps egnn knn ...] [--json]

The swaps are the recipes in ``recipes/swaps/``: each differs from the reference
recipe (``recipes/sand2d.yaml``) in one component (processor, integrator or graph
builder). That component, with its own parameters, replaces the base recipe's
(message-passing steps stay the base's, so every row has one model size), and
each variant trains from scratch for ``--steps`` steps on ``--data`` with the same
seed, batches and schedule, one after the other (never at once). Then it rolls out
the first ``--cases`` test trajectories of ``--held-out`` (unseen seeds) and reports:

- one-step loss on the valid split (normalised acceleration MSE, noise-free);
- final-cloud Sinkhorn error (% of the domain) and runout error (% of the true
  runout), median and worst over the cases;
- training seconds per step and rollout seconds per case (median, after one untimed
  rollout), and their ratios to the base (measured in the same run, so machine load
  hits every row alike).

Swaps that cannot run here are listed with the reason (an optional module not
installed, data of another kind: periodic boxes, a plugin material).
"""

from __future__ import annotations

import argparse
import copy
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import torch
import yaml

ROOT = Path(__file__).resolve().parents[1]
COMPONENTS = ("graph_builder", "processor", "integrator")


def swapped_component(swap: dict, reference: dict) -> tuple[str, dict] | None:
    """(kind, spec) of the one component ``swap``'s model changes against ``reference``'s, or None."""
    changed = [
        k for k in COMPONENTS if swap["model"].get(k, {}).get("name") != reference["model"].get(k, {}).get("name")
    ]
    if len(changed) != 1:
        return None
    return changed[0], swap["model"][changed[0]]


def variant(base: dict, kind: str, spec: dict, data: Path, steps: int, seed: int, out: Path) -> dict:
    """``base`` with its ``kind`` replaced by ``spec`` (the base's message-passing steps kept), for this run."""
    raw = copy.deepcopy(base)
    spec = dict(spec)
    if kind == "processor":
        spec["message_passing_steps"] = base["model"]["processor"].get("message_passing_steps", 10)
    raw["model"][kind] = spec
    raw["dataset"]["path"] = str(data)
    raw["seed"] = seed
    raw["output_dir"] = str(out)
    training = raw["training"]
    training.update(steps=steps, validate_every=steps, checkpoint_every=steps, validation_rollouts=0, log_every=steps)
    training.pop("best_metric", None)
    return raw


def not_runnable(kind: str, spec: dict, swap: dict, registry) -> str | None:
    """Why a swap cannot be measured on the base's data here, or None."""
    from gns_framework.cli.check import missing_module

    cls = registry.get(kind, spec["name"])
    missing = [m for m in getattr(cls, "optional_modules", ()) if missing_module(m) is not None]
    if missing:
        return f"needs {', '.join(missing)} (not installed)"
    if swap["model"].get("periodic"):
        return "needs periodic data (recipes/swaps/periodic_radius.yaml says where to get it)"
    return None


def measure(raw: dict, registry, held_out: Path, cases: int) -> dict:
    """Train ``raw``, then score its rollouts of the held-out cases."""
    from gns_framework.assembly.data import open_dataset
    from gns_framework.config.recipe import validate_recipe
    from gns_framework.evaluation.candidates import cases_from_split, granular_particle_types, learned_positions
    from gns_framework.evaluation.report import Prediction, score_prediction
    from gns_framework.training.trainer import Trainer

    recipe = validate_recipe(raw, registry)
    trainer = Trainer(recipe, registry, progress=False)
    started = time.perf_counter()
    trainer.train()
    train_seconds = time.perf_counter() - started
    one_step = trainer.validate()["valid_one_step_loss"]
    simulator = trainer.simulator.eval()
    data = open_dataset(recipe.dataset, registry, held_out)
    test = cases_from_split(data.split("test"))[:cases]
    granular = granular_particle_types(simulator.setup, registry)
    sinkhorn, runout, rollout_seconds = [], [], []
    learned_positions(simulator, test[0], "cpu")  # untimed: the first rollout compiles kernels and fills caches
    for case in test:
        started = time.perf_counter()
        positions = learned_positions(simulator, case, "cpu")
        rollout_seconds.append(time.perf_counter() - started)
        scores = score_prediction(
            Prediction(positions),
            case,
            simulator.setup.history,
            data.metadata(),
            granular_types=granular,
            kinematic_types=simulator.setup.kinematic_types,
            metrics=[m for m in registry.metrics() if m.name in ("sinkhorn_final_pct", "runout_error_pct")],
        )
        sinkhorn.append(float(scores["sinkhorn_final_pct"].item()))
        runout.append(float(scores["runout_error_pct"].item()))
    trainer.close()
    return {
        "one_step_loss": one_step,
        "sinkhorn_median": statistics.median(sinkhorn),
        "sinkhorn_worst": max(sinkhorn),
        "runout_median": statistics.median(runout),
        "runout_worst": max(runout),
        "train_s_per_step": train_seconds / recipe.training.steps,
        "rollout_s": statistics.median(rollout_seconds),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True, help="training dataset (the base recipe's kind)")
    parser.add_argument("--held-out", type=Path, required=True, help="dataset whose test split holds unseen scenes")
    parser.add_argument("--base", type=Path, default=ROOT / "recipes" / "sizes" / "sand2d_fast_3x32.yaml")
    parser.add_argument("--steps", type=int, default=1500)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--cases", type=int, default=10)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument(
        "--swaps",
        nargs="+",
        metavar="RECIPE",
        help="only these recipes of recipes/swaps/ (file stems); the base always runs",
    )
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)

    from gns_framework.plugins import load_registry

    registry = load_registry()
    base = yaml.safe_load(args.base.read_text())
    base["training"]["threads"] = args.threads
    reference = yaml.safe_load((ROOT / "recipes" / "sand2d.yaml").read_text())
    rows: list[tuple[str, str, dict, str | None]] = [("(base)", base["model"]["processor"]["name"], {}, None)]
    for path in sorted((ROOT / "recipes" / "swaps").glob("*.yaml")):
        if args.swaps and path.stem not in args.swaps:
            continue
        swap = yaml.safe_load(path.read_text())
        found = swapped_component(swap, reference)
        if found is None:
            rows.append((path.stem, "-", {}, "changes the materials, not a component (data from its own scene)"))
            continue
        kind, spec = found
        rows.append((kind, spec["name"], spec, not_runnable(kind, spec, swap, registry)))

    results = []
    with tempfile.TemporaryDirectory() as scratch:
        for kind, name, spec, reason in rows:
            if reason is not None:
                results.append({"kind": kind, "name": name, "skipped": reason})
                print(f"{kind:14s} {name:28s} not measured: {reason}", flush=True)
                continue
            per_seed = []
            for seed in args.seeds:
                out = Path(scratch) / f"{kind}-{name}-{seed}"
                own = ("processor", base["model"]["processor"]) if kind == "(base)" else (kind, spec)
                raw = variant(base, *own, args.data, args.steps, seed, out)
                per_seed.append(measure(raw, registry, args.held_out, args.cases))
            merged = {k: statistics.median(r[k] for r in per_seed) for k in per_seed[0]}
            results.append({"kind": kind, "name": name, **merged, "seeds": per_seed})
            print(
                f"{kind:14s} {name:28s} one-step {merged['one_step_loss']:.3g}  "
                f"sinkhorn {merged['sinkhorn_median']:.2f}/{merged['sinkhorn_worst']:.2f} %  "
                f"runout {merged['runout_median']:.1f}/{merged['runout_worst']:.1f} %  "
                f"{merged['train_s_per_step']:.3f} s/step  {merged['rollout_s']:.2f} s/rollout",
                flush=True,
            )
    base_row = results[0]
    print(
        "\n| kind | swap | one-step loss | Sinkhorn % median / worst | runout % median / worst | "
        "train step vs base | rollout vs base |"
    )
    print("|---|---|---:|---:|---:|---:|---:|")
    for row in results:
        if "skipped" in row:
            print(f"| {row['kind']} | `{row['name']}` | not measured: {row['skipped']} | | | | |")
            continue
        print(
            f"| {row['kind']} | `{row['name']}` | {row['one_step_loss']:.3g} | {row['sinkhorn_median']:.2f} / "
            f"{row['sinkhorn_worst']:.2f} | {row['runout_median']:.1f} / {row['runout_worst']:.1f} | "
            f"{row['train_s_per_step'] / base_row['train_s_per_step']:.2f}x | "
            f"{row['rollout_s'] / base_row['rollout_s']:.2f}x |"
        )
    print(
        f"\n{args.base.name}, {args.steps} steps, seeds {args.seeds}, {args.cases} held-out cases, "
        f"{args.threads} thread(s); base: {base_row['train_s_per_step']:.3f} s/step, {base_row['rollout_s']:.2f} "
        "s/rollout"
    )
    if args.json:
        print(json.dumps({"base": str(args.base), "steps": args.steps, "seeds": args.seeds, "rows": results}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
