"""What a Verlet-list skin saves in a rollout: the same rollout, searched less often.

Rolls a trained model out on the test cases of a dataset twice per case, interleaved:
with its recipe's radius graph searched every frame, and with the search's pairs kept
for later frames under a skin of S connectivity radii (``graph_builder: {name: radius,
skin: S}``, ``plugins/gns_builtins/_kernels/verlet_list.py``). It prints per case the
wall time of each, their ratio, the searches the skin needed out of the frames, and
the largest difference between the two rollouts' positions (0: the graphs were the
same, as they must be). Then the medians. The machine's load hits both alike.

Usage::

    python benchmarks/generalization.py --held-out 20 --out runs/generalization     # makes the data once
    python benchmarks/skin.py --model models/sand2d_general.pt \\
        --dataset runs/generalization/held_out --skins 0.25,0.5,1 --threads 1 [--json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", type=Path, default=ROOT / "models" / "sand2d_general.pt")
    parser.add_argument("--dataset", type=Path, required=True, help="dataset folder; its test split is rolled out")
    parser.add_argument("--skins", default="0.5", help="skins to compare, in connectivity radii (default 0.5)")
    parser.add_argument("--cases", type=int, default=10, help="test cases rolled out (default 10)")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)

    from gns_builtins._kernels.verlet_list import VerletList
    from gns_framework.assembly.data import open_dataset
    from gns_framework.assembly.trained import load_trained
    from gns_framework.model.rollout import rollout
    from gns_framework.plugins import load_registry

    registry = load_registry()
    model = load_trained(args.model, registry, "cpu")
    simulator = model.simulator.eval()
    builder = simulator.graph_builder
    if not hasattr(builder, "verlet"):
        parser.error(f"{args.model}: its graph builder ({builder.name}) takes no skin")
    radius = simulator.setup.connectivity_radius
    skins = [float(s) for s in args.skins.split(",")]
    cases = list(open_dataset(model.recipe.dataset, registry, args.dataset).split("test"))[: args.cases]

    def timed(trajectory, skin: float):
        builder.verlet = VerletList(radius, skin * radius) if skin > 0 else None
        started = time.perf_counter()
        with torch.no_grad():
            result = rollout(simulator, trajectory)
        searches = builder.verlet.searches if builder.verlet is not None else result.predicted.shape[0]
        return time.perf_counter() - started, result.predicted, searches

    rows = []
    print(f"{args.model} on {args.dataset} (test): seconds per rollout, searches of the radius graph")
    print(f"{'case':<20} {'frames':>6} {'no skin s':>10} " + " ".join(f"{f'skin {s:g}':>22}" for s in skins))
    for trajectory in cases:
        timed(trajectory, 0.0)  # warm-up: lazy choices, allocator
        base_seconds, base, _ = timed(trajectory, 0.0)
        row = {"case": trajectory.key, "frames": int(base.shape[0]), "seconds": base_seconds, "skins": {}}
        for skin in skins:
            seconds, predicted, searches = timed(trajectory, skin)
            difference = float(np.abs(predicted - base).max())
            row["skins"][skin] = {
                "seconds": seconds,
                "ratio": base_seconds / seconds,
                "searches": searches,
                "max_difference": difference,
            }
        rows.append(row)
        cells = " ".join(
            f"{r['ratio']:>6.2f}x {r['searches']:>4} d={r['max_difference']:.0e}" for r in row["skins"].values()
        )
        print(f"{trajectory.key:<20} {row['frames']:>6} {base_seconds:>10.2f} {cells}")
    builder.verlet = None
    for skin in skins:
        ratio = statistics.median(r["skins"][skin]["ratio"] for r in rows)
        share = statistics.median(r["skins"][skin]["searches"] / r["frames"] for r in rows)
        worst = max(r["skins"][skin]["max_difference"] for r in rows)
        print(
            f"skin {skin:g}: median speed-up {ratio:.2f}x, searches {share:.0%} of frames, largest difference {worst:g}"
        )
    if args.json:
        print(json.dumps({"model": str(args.model), "rows": rows}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
