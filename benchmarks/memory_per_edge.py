"""Memory per edge of a training step and of a rollout step, measured on the CPU, and the largest scenes it allows.

Usage:
    python benchmarks/memory_per_edge.py [--dim 3] [--sizes 2000 6000] [--runs 3] [--json]

The paper's model (latent 128, 10 steps) on the lattice benchmark scene. Each
(size, mode) runs in a fresh process that keeps freed memory in its heap
(gns_framework/allocator.py), so its peak resident size is the peak of what it
allocated; the slope of that peak between two scene sizes over the slope of the
edge count is the memory per edge, without the fixed costs (interpreter, torch,
the model). The heap's layout makes one run's peak vary by ~10 % at these sizes:
each point is the smallest of ``--runs`` runs. Modes: rollout (inference), and training with stored or recomputed
activations (``training.recompute_activations``), each in float32 and under
bfloat16 autocast. The projection divides a GPU's memory, less 4 GiB for the
CUDA context and the model, by the bytes per edge: edges, and particles at ~20
neighbours each (the benchmark scene's density; 3D scenes of the reference run
~20-30).
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
from pathlib import Path

MODES = [
    ("rollout", "float32", False), ("rollout", "bfloat16", False),
    ("train", "float32", False), ("train", "float32", True),
    ("train", "bfloat16", False), ("train", "bfloat16", True),
]
GPUS_GB = {"80 GB (A100/H100)": 80, "141 GB (H200)": 141}
RESERVED_GB = 4
"""CUDA context, the model, its optimiser state and the allocator's slack."""


def one(particles: int, dim: int, phase: str, precision: str, recompute: bool) -> dict:
    """Peak resident bytes of this process after one warm-up and one measured step, and the edge count."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import torch
    from step_time import Stepper, benchmark_model

    from gns_framework.activation_memory import set_recompute_activations
    from gns_framework.allocator import keep_freed_memory

    keep_freed_memory()
    torch.set_num_threads(1)
    set_recompute_activations(recompute)
    scene, simulator = benchmark_model(particles, dim)
    stepper = Stepper(simulator, scene.batch, precision=precision)
    step = stepper.rollout_step if phase == "rollout" else stepper.train_step
    for _ in range(2):
        step()
    edges = simulator.build_graph(scene.batch.position_sequence, scene.batch).num_edges
    return {"edges": edges, "peak_bytes": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024}


def measure(sizes: list[int], dim: int, runs: int) -> list[dict]:
    rows = []
    for phase, precision, recompute in MODES:
        points = []
        for particles in sizes:
            command = [sys.executable, __file__, "--one", str(particles), "--dim", str(dim), "--phase", phase,
                       "--precision", precision] + (["--recompute"] if recompute else [])
            results = [json.loads(subprocess.run(command, check=True, capture_output=True, text=True).stdout)
                       for _ in range(runs)]
            points.append(min(results, key=lambda r: r["peak_bytes"]))
        (small, large) = points[0], points[-1]
        per_edge = (large["peak_bytes"] - small["peak_bytes"]) / (large["edges"] - small["edges"])
        row = {"phase": phase, "precision": precision, "activations": "recomputed" if recompute else "stored",
               "bytes_per_edge": per_edge, "edges": [p["edges"] for p in points]}
        for gpu, gb in GPUS_GB.items():
            edges = (gb - RESERVED_GB) * 2**30 / per_edge
            row[gpu] = {"edges": edges, "particles_at_20_neighbours": edges / 20}
        rows.append(row)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dim", type=int, choices=(2, 3), default=3)
    parser.add_argument("--sizes", type=int, nargs=2, default=[2000, 6000])
    parser.add_argument("--runs", type=int, default=3, help="runs per point; the smallest peak counts")
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--one", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--phase", help=argparse.SUPPRESS)
    parser.add_argument("--precision", help=argparse.SUPPRESS)
    parser.add_argument("--recompute", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        print(json.dumps(one(args.one, args.dim, args.phase, args.precision, args.recompute)))
        return
    rows = measure(args.sizes, args.dim, args.runs)
    if args.json:
        print(json.dumps(rows, indent=2))
        return
    print(f"| step | precision | activations | bytes/edge | " + " | ".join(f"largest on {g}" for g in GPUS_GB) + " |")
    print("|---|---|---|---|" + "---|" * len(GPUS_GB))
    for r in rows:
        largest = " | ".join(
            f"{r[g]['edges'] / 1e6:.0f}M edges, ~{r[g]['particles_at_20_neighbours'] / 1e6:.1f}M particles" for g in GPUS_GB
        )
        print(f"| {r['phase']} | {r['precision']} | {r['activations']} | {r['bytes_per_edge']:,.0f} | {largest} |")


if __name__ == "__main__":
    main()
