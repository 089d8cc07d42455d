"""Memory per edge of a training step and of a rollout step, measured on the CPU, and the largest scenes it allows.

Usage:
    python benchmarks/memory_per_edge.py [--dim 3] [--sizes 1000 3000] [--json]

The paper's model (latent 128, 10 steps) on the lattice benchmark scene. One step
after a warm-up runs under the torch profiler with ``profile_memory``: every
allocation and free of torch's CPU allocator is an event, so the running sum of
their sizes in time order is the memory held by tensors, and its maximum the
step's peak above what was held before it (op by op: a temporary that lives
inside one op is not seen). The slope of that peak between two scene sizes over
the slope of the edge count is the memory per edge, without anything that does
not grow with the scene. Modes: rollout (inference), and training with stored or
recomputed activations (``training.recompute_activations``), each in float32 and
under bfloat16 autocast.

The projection divides a GPU's memory, less 4 GiB for the CUDA context, the model,
its optimiser state and the allocator's slack, by the bytes per edge: edges, and
particles at ~20 edges each (the benchmark scene's density, self-edges included).
The GPU's own figures come from ``benchmarks/gpu_check.sh`` (``bytes_per_edge``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from step_time import Stepper, benchmark_model

from gns_framework.runtime.activation_memory import set_recompute_activations

MODES = [
    ("rollout", "float32", False),
    ("rollout", "bfloat16", False),
    ("train", "float32", False),
    ("train", "float32", True),
    ("train", "bfloat16", False),
    ("train", "bfloat16", True),
]
GPUS_GB = {"80 GB (A100/H100)": 80, "141 GB (H200)": 141}
RESERVED_GB = 4
NEIGHBOURS = 20


def step_peak_bytes(step) -> int:
    """Peak bytes held by tensors during ``step()`` above those held before it."""
    with torch.profiler.profile(activities=[torch.profiler.ProfilerActivity.CPU], profile_memory=True) as profile:
        step()
    events = sorted((e for e in profile.events() if e.self_cpu_memory_usage), key=lambda e: e.time_range.start)
    held = peak = 0
    for event in events:
        held += event.self_cpu_memory_usage
        peak = max(peak, held)
    return peak


def one(particles: int, dim: int, phase: str, precision: str, recompute: bool) -> dict:
    set_recompute_activations(recompute)
    try:
        scene, simulator = benchmark_model(particles, dim)
        stepper = Stepper(simulator, scene.batch, precision=precision)
        step = stepper.rollout_step if phase == "rollout" else stepper.train_step
        step()  # warm-up: optimiser state, caches
        edges = simulator.build_graph(scene.batch.position_sequence, scene.batch).num_edges
        return {"edges": edges, "peak_bytes": step_peak_bytes(step)}
    finally:
        set_recompute_activations(False)


def measure(sizes: list[int], dim: int) -> list[dict]:
    rows = []
    for phase, precision, recompute in MODES:
        small, large = (one(particles, dim, phase, precision, recompute) for particles in sizes)
        per_edge = (large["peak_bytes"] - small["peak_bytes"]) / (large["edges"] - small["edges"])
        row = {
            "phase": phase,
            "precision": precision,
            "activations": "recomputed" if recompute else "stored",
            "bytes_per_edge": per_edge,
            "edges": [small["edges"], large["edges"]],
        }
        for gpu, gb in GPUS_GB.items():
            edges = (gb - RESERVED_GB) * 2**30 / per_edge
            row[gpu] = {"edges": edges, "particles": edges / NEIGHBOURS}
        rows.append(row)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dim", type=int, choices=(2, 3), default=3)
    parser.add_argument("--sizes", type=int, nargs=2, default=[1000, 3000])
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    rows = measure(args.sizes, args.dim)
    if args.json:
        print(json.dumps(rows, indent=2))
        return
    print("| step | precision | activations | bytes/edge | " + " | ".join(f"largest on {g}" for g in GPUS_GB) + " |")
    print("|---|---|---|---|" + "---|" * len(GPUS_GB))
    for r in rows:
        largest = " | ".join(
            f"{r[g]['edges'] / 1e6:.0f}M edges, {r[g]['particles'] / 1e6:.2f}M particles" for g in GPUS_GB
        )
        print(f"| {r['phase']} | {r['precision']} | {r['activations']} | {r['bytes_per_edge']:,.0f} | {largest} |")


if __name__ == "__main__":
    main()
