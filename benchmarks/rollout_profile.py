"""Where a learned rollout step spends its time, at several particle counts.

The demo's sand column refined to about ``--particles`` particles (as in
benchmarks/learned_vs_simulator.py), rolled out by a shipped model's architecture
with its connectivity radius scaled to the spacing. Each stage of one rollout step
is timed by wrapping the component that does it (CPU: nothing runs asynchronously,
so a stage's wall clock is its cost):

    graph        the graph builder's neighbour search (edges within the radius)
    features     node features (velocities, walls, properties) and edge features
    encoder      node and edge MLPs
    processor    message passing (or the grid processor)
    decoder      the output MLP and denormalisation
    integrator   positions from the predicted accelerations
    rest         what the step does besides: the window, masks, copies, Python

Usage::

    python benchmarks/rollout_profile.py --particles 300 3000 30000 --models fast grid --threads 1

Prints, per model and size, the milliseconds per step and each stage's share, the
median of ``--repeats`` steps after a warm-up step; the last line is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from learned_vs_simulator import learned_model, refined_scene

STAGES = ("graph", "features", "encoder", "processor", "decoder", "integrator", "rest")


class StageClock:
    """Wall-clock seconds spent inside each wrapped method, per stage, for the current step."""

    def __init__(self):
        self.seconds: dict[str, float] = defaultdict(float)

    def wrap(self, owner, method: str, stage: str) -> None:
        inner = getattr(owner, method)

        def timed(*args, **kwargs):
            started = time.perf_counter()
            try:
                return inner(*args, **kwargs)
            finally:
                self.seconds[stage] += time.perf_counter() - started

        setattr(owner, method, timed)

    def wrap_module(self, module: torch.nn.Module, stage: str) -> None:
        """Time a module's whole call (hooks: a child module cannot be replaced by a function)."""
        started: list[float] = []
        module.register_forward_pre_hook(lambda *_: started.append(time.perf_counter()))

        def finished(*_):
            self.seconds[stage] += time.perf_counter() - started.pop()

        module.register_forward_hook(finished)


def profile(simulator, sample, repeats: int) -> dict:
    """Median milliseconds per step and each stage's median share of it."""
    from gns_framework.data.batch import ParticleBatch

    clock = StageClock()
    clock.wrap(simulator.graph_builder, "build", "graph")
    clock.wrap(simulator.features, "node_features", "features")
    clock.wrap(simulator.features, "edge_features", "features")
    clock.wrap_module(simulator.encoder, "encoder")
    clock.wrap_module(simulator.processor, "processor")
    clock.wrap_module(simulator.decoder, "decoder")
    clock.wrap(simulator.output_stats, "denormalize", "decoder")
    clock.wrap(simulator.integrator, "next_position", "integrator")
    position = torch.from_numpy(np.concatenate([b.position for b in sample.blocks])).float()
    n = position.shape[0]
    history = simulator.setup.history
    # A column just released: the last frames fall a little, so the step sees motion.
    fall = torch.linspace(-1e-4 * (history - 1), 0.0, history)
    sequence = position[:, None].repeat(1, history, 1)
    sequence[..., -1] += fall
    state = ParticleBatch(
        position_sequence=sequence,
        particle_type=torch.full((n,), 6, dtype=torch.long),
        batch=torch.zeros(n, dtype=torch.long),
        num_examples=1,
        material_property=torch.full((n, 1), 0.7),
    )
    totals, shares = [], defaultdict(list)
    with torch.inference_mode():
        for repeat in range(repeats + 1):
            clock.seconds.clear()
            started = time.perf_counter()
            simulator.predict_next_position(state)
            total = time.perf_counter() - started
            if not repeat:
                continue  # the warm-up step
            totals.append(total)
            # No stage calls another, so the stages and the rest add up to the step.
            clock.seconds["rest"] = total - sum(clock.seconds[s] for s in STAGES if s != "rest")
            for stage in STAGES:
                shares[stage].append(clock.seconds[stage] / total)
    return {
        "particles": n,
        "ms_per_step": 1e3 * statistics.median(totals),
        "share": {stage: statistics.median(values) for stage, values in shares.items()},
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--particles", type=int, nargs="+", default=[300, 3000, 30000])
    parser.add_argument("--models", nargs="+", choices=("fast", "grid", "reference"), default=["fast", "grid"])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    from gns_framework.plugins import load_registry

    registry = load_registry()
    rows = []
    for particles in args.particles:
        scene, sample = refined_scene(particles)
        # The radius follows the spacing: the data's grid over this one.
        radius_scale = 48 / scene.domain.grid
        for kind in args.models:
            simulator, stride = learned_model(kind, registry, radius_scale)
            row = {"model": kind, "frames_per_step": stride, **profile(simulator, sample, args.repeats)}
            rows.append(row)
            stages = ", ".join(f"{stage} {100 * row['share'][stage]:.0f} %" for stage in STAGES)
            print(f"{kind:9s} {row['particles']:7d} particles: {row['ms_per_step']:8.2f} ms per step; {stages}")
            sys.stdout.flush()
    print(json.dumps({"threads": args.threads, "rows": rows}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
