"""Throughput of batched rollouts: B scenes stepped as one batch against the same B one at a time.

A parametric study: one demo collapse (the first test collapse of ``--data``) with ``--scenes``
friction values spread over the model's trained range, rolled out by ``--model``
(default the shipped models/sand2d_fast.pt) one scene at a time and in batches of each
``--batch`` size, back to back in one run so machine load hits them alike. Prints the
seconds per scene of each and the ratio to one at a time (above 1: the batch is faster),
and the largest difference of a batched scene's final frame from its own rollout.

Usage::

    python benchmarks/batched_rollout.py --data data/demo_sand_2d --scenes 64 --batch 8 64 --threads 1
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    from gns_framework.assembly.data import open_dataset
    from gns_framework.assembly.trained import load_trained
    from gns_framework.model.batched_rollout import rollout_batch
    from gns_framework.model.rollout import rollout
    from gns_framework.plugins import load_registry

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", type=Path, default=ROOT / "models" / "sand2d_fast.pt")
    parser.add_argument("--data", type=Path, required=True, help="a dataset of the model's scene family")
    parser.add_argument("--scenes", type=int, default=64, help="friction values (scenes) of the study")
    parser.add_argument("--batch", type=int, nargs="+", default=[8, 64], help="batch sizes to time")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)

    registry = load_registry()
    model = load_trained(args.model, registry)
    dataset = open_dataset(model.recipe.dataset, registry, args.data)
    base = dataset.split("test")[0]
    if base.material_property is None or model.envelope is None or "friction" not in model.envelope.properties:
        print(f"{args.model}: needs a model with a friction property and an envelope", file=sys.stderr)
        return 2
    low, high = model.envelope.properties["friction"]
    column = list(model.simulator.setup.property_names).index("friction")
    scenes = []
    for friction in np.linspace(low, high, args.scenes):
        properties = base.material_property.copy()
        properties[:, column] = friction
        scenes.append(replace(base, material_property=properties, key=f"friction_{friction:.3f}"))

    def timed(function):
        start = time.perf_counter()
        result = function()
        return time.perf_counter() - start, result

    rollout(model.simulator, scenes[0])  # warm-up
    alone_s, alone = timed(lambda: [rollout(model.simulator, s) for s in scenes])
    per_scene = alone_s / len(scenes)
    print(
        f"{args.model}: {len(scenes)} scenes of {base.num_particles} particles, "
        f"{alone[0].num_steps} learned steps each, {args.threads} thread(s)"
    )
    print(f"{'batch':>6} {'s per scene':>12} {'vs one at a time':>17} {'max |diff| final frame (m)':>27}")
    print(f"{1:>6} {per_scene:>12.4f} {1.0:>17.2f} {0.0:>27.2e}")
    for size in args.batch:
        seconds, batched = timed(
            lambda size=size: [
                r for i in range(0, len(scenes), size) for r in rollout_batch(model.simulator, scenes[i : i + size])
            ]
        )
        diff = max(float(np.abs(b.predicted[-1] - a.predicted[-1]).max()) for a, b in zip(alone, batched, strict=True))
        print(f"{size:>6} {seconds / len(scenes):>12.4f} {per_scene / (seconds / len(scenes)):>17.2f} {diff:>27.2e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
