"""Does a model reproduce the scenes it was trained on? Its deposit errors on its own training trajectories.

A model whose worst held-out scenes are as far off as its worst training scenes does not lack data like them: it
has not fitted them (a rollout of 60 learned steps can drift where every single step was fitted). This rolls the
model out on its training split (the first frame offset of each trajectory, from its first ``history`` frames, as a
held-out scene is rolled out), and prints the scenes it misses most, the share over 10 and 15 % in extent or height,
and the same for the scenes with and without an obstacle.

Usage::

    python benchmarks/training_fit.py --model models/sand2d_general_fast.pt --threads 1 [--limit N] [--json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from second_opinion import BAD, deposit


def first_offsets(cases):
    """The cases of a split read with ``stride_offsets: all`` that start at the stored frame 0 (keys without ``+k``)."""
    return [case for case in cases if "+" not in case.key]


def scene_rows(model, data: Path, registry, split: str, limit: int | None) -> list[dict]:
    """Per trajectory of ``split``: the learned extent and height errors (%) and whether it holds fixed particles."""
    from gns_framework.assembly.data import open_dataset
    from gns_framework.evaluation.candidates import cases_from_split, granular_particle_types, learned_prediction

    data_set = open_dataset(model.recipe.dataset, registry, data)
    metadata, setup = data_set.metadata(), model.simulator.setup
    granular = granular_particle_types(setup, registry)
    rows = []
    for case in first_offsets(cases_from_split(data_set.split(split)))[:limit]:
        prediction = learned_prediction(model.simulator, case, "cpu", guard=model.rollout_guard())
        rows.append(
            {
                "scene": case.key,
                **deposit(prediction, case, setup.history, metadata, granular),
                "obstacle": bool(np.isin(case.particle_type, setup.kinematic_types).any()),
            }
        )
    return rows


def summary(rows: list[dict]) -> dict:
    """Scenes, median and shares over 10 and ``BAD`` % of the worse of extent and height, overall and by obstacle."""

    def of(group: list[dict]) -> dict:
        worst = [max(r["extent"], r["height"]) for r in group]
        return {
            "scenes": len(group),
            "median_pct": statistics.median(worst) if worst else float("nan"),
            "over_10": sum(w > 10 for w in worst),
            f"over_{BAD:g}": sum(w > BAD for w in worst),
        }

    return {
        "all": of(rows),
        "with_obstacle": of([r for r in rows if r["obstacle"]]),
        "without_obstacle": of([r for r in rows if not r["obstacle"]]),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", type=Path, required=True)
    parser.add_argument("--data", type=Path, help="its training data (default: the recipe's dataset path)")
    parser.add_argument("--split", default="train")
    parser.add_argument("--limit", type=int, help="the first N trajectories only")
    parser.add_argument("--worst", type=int, default=20, help="print the N scenes it misses most")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--json", action="store_true", help="also print the rows and summary as one JSON line")
    args = parser.parse_args(argv)
    import torch

    torch.set_num_threads(args.threads)
    from gns_framework.assembly.trained import load_trained
    from gns_framework.plugins import load_registry

    registry = load_registry()
    model = load_trained(args.model, registry, torch.device("cpu"))
    rows = scene_rows(model, args.data or Path(model.recipe.dataset.path), registry, args.split, args.limit)
    print(f"{args.model} on its {args.split} split: extent / height error against the data, %")
    for row in sorted(rows, key=lambda r: -max(r["extent"], r["height"]))[: args.worst]:
        print(f"{row['scene']:<20} {row['extent']:6.1f} {row['height']:6.1f}{'  obstacle' if row['obstacle'] else ''}")
    result = summary(rows)
    for group, figures in result.items():
        print(
            f"{group:<17} {figures['scenes']:4d} scenes, median {figures['median_pct']:.1f} %, over 10 %: "
            f"{figures['over_10']}, over {BAD:g} %: {figures[f'over_{BAD:g}']}"
        )
    if args.json:
        print(json.dumps({"model": str(args.model), "rows": rows, **result}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
