"""Operations dispatched and host read-backs per rollout step and per training step, on the GPU code path run on the
CPU.

Usage:
    python benchmarks/step_budget.py [--particles 10000] [--dim 3] [--top 15] [--chunked] [--json]
        [--graph-builder radius|radius_fixed_capacity]

On a GPU every operation is at least one kernel launch (a few microseconds of host
time each) and every read-back makes the host wait for the device: a scene of 10k
particles whose step launches a thousand operations is bound by the launches, not by
the arithmetic (issue 45). This counts both where no GPU is needed: the paper's model
(latent 128, 10 steps) on the lattice scene, with every choice a GPU run makes taken
on the CPU (no read-back where the accelerators avoid one, ordered sums, the Triton
edge block), under a ``TorchDispatchMode`` that sees every ATen operation torch
dispatches. A Triton kernel is one launch: here its launches are counted and not run
(the interpreter would take minutes at this size), so values are not computed and the
figures are counts only. Read-backs are the synchronising operations of
:class:`~gns_framework.runtime.sync_counter.SyncCounter` plus the explicit
``host_sync.read_back`` calls (the graph builder's edge count).

One line per phase (graph build, whole rollout step, whole training step): every
dispatched operation (``ops``), those that launch a kernel on a GPU (``launching``: not
views, dtype queries, same-dtype conversions or allocations), read-backs, and the most
frequent launching operations; the last line (``--json``) is one JSON object with
``ops_per_rollout_step``, ``syncs_per_rollout_step``, ``ops_per_training_step``,
``syncs_per_training_step``, and the graph build's ``ops_per_graph_build``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from collections import Counter
from pathlib import Path
from types import SimpleNamespace

import torch
from torch.utils._python_dispatch import TorchDispatchMode

sys.path.insert(0, str(Path(__file__).resolve().parent))

from lattice_scene import lattice_scene

from gns_framework.runtime.sync_counter import SyncCounter

NO_KERNEL = frozenset(
    {
        "aten.view",
        "aten._unsafe_view",
        "aten.reshape",
        "aten.slice",
        "aten.select",
        "aten.t",
        "aten.transpose",
        "aten.permute",
        "aten.expand",
        "aten.unsqueeze",
        "aten.squeeze",
        "aten.as_strided",
        "aten.detach",
        "aten.alias",
        "aten.unbind",
        "aten.split",
        "aten.split_with_sizes",
        "aten.chunk",
        "aten.narrow",
        "aten.promote_types",
        "aten.result_type",
        "aten.is_same_size",
        "aten.sym_size",
        "aten.sym_stride",
        "aten.to",
        "aten.lift_fresh",
        "aten.empty",
        "aten.empty_like",
        "aten.empty_strided",
    }
)
"""Operations that launch no kernel: views, dtype queries, conversions to the same dtype (a real conversion
shows as ``aten._to_copy``) and allocations (the caching allocator hands out memory without a launch)."""


class OperationCounter(TorchDispatchMode):
    """Counts every ATen operation dispatched while inside, by name, and the synchronising ones apart."""

    def __init__(self):
        super().__init__()
        self.operations: Counter[str] = Counter()
        self.syncs = SyncCounter()

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        self.operations[str(func.overloadpacket)] += 1
        return self.syncs.__torch_dispatch__(func, types, args, kwargs)


class Launches:
    """Stand-ins for the Triton kernels that count launches instead of running them."""

    def __init__(self, counter: OperationCounter | None = None):
        self.counter = counter

    def kernel(self, name: str):
        budget = self

        class Kernel:
            def __getitem__(self, grid):
                def launch(*args, **kwargs):
                    if budget.counter is not None:
                        budget.counter.operations[f"triton.{name}"] += 1

                return launch

        return Kernel()

    def module(self):
        return SimpleNamespace(
            forward_kernel=self.kernel("forward_kernel"),
            backward_kernel=self.kernel("backward_kernel"),
            segment_sum_kernel=self.kernel("segment_sum_kernel"),
        )


@contextlib.contextmanager
def gpu_choices(launches: Launches, read_backs: list, triton: bool = True):
    """Inside: the accelerators' choices on the CPU, Triton launches counted, explicit read-backs recorded."""
    from gns_builtins._kernels import cell_list, chunked, edge_block, fixed_capacity, fused_kernels, triton_edge_block
    from gns_framework.model import learned_simulator, rollout
    from gns_framework.training import trainer

    def counted_read_back(tensor):
        read_backs.append(tuple(tensor.shape))
        return tensor.tolist()

    patches = [(module, "avoids_read_backs", lambda device: True) for module in (learned_simulator, rollout, trainer)]
    patches += [
        (edge_block, "avoids_read_backs", lambda device: True),
        (edge_block, "needs_ordered_sums", lambda device: True),
        (triton_edge_block, "applies", lambda e, hidden, num_weights: triton and num_weights in (2, 3)),
        (triton_edge_block, "triton_module", launches.module),
        (cell_list, "read_back", counted_read_back),
        (fixed_capacity, "read_back", counted_read_back),
        (cell_list, "candidates_per_chunk", lambda device: cell_list.CANDIDATES_PER_CHUNK_ACCELERATOR),
        # The chunked edge block as on a GPU (--chunked): chunks of the accelerators' size, no CPU C loops.
        (edge_block, "chunk_size", lambda device: chunked.ROWS_PER_CHUNK_ACCELERATOR),
        (fused_kernels, "applies", lambda *tensors: False),
    ]
    saved = [(module, name, getattr(module, name)) for module, name, _ in patches]
    try:
        for module, name, value in patches:
            setattr(module, name, value)
        yield
    finally:
        for module, name, value in saved:
            setattr(module, name, value)


def count(step, launches: Launches, read_backs: list) -> tuple[Counter[str], int]:
    """Operations of one ``step()`` and its read-backs (synchronising operations plus explicit reads)."""
    counter = OperationCounter()
    launches.counter = counter
    read_backs.clear()
    with counter:
        step()
    launches.counter = None
    return counter.operations, counter.syncs.total + len(read_backs)


def measure(particles: int, dim: int, triton: bool = True, graph_builder: str = "radius") -> dict:
    """The counts for the paper's model with ``graph_builder`` (a built-in radius builder's name)."""
    from gns_framework.assembly.learned import build_learned_simulator
    from gns_framework.config.recipe import ModelSpec, OptimizerSpec
    from gns_framework.model.loss import masked_acceleration_loss
    from gns_framework.model.noise import random_walk_noise
    from gns_framework.model.rollout import capacity_checks, rollout_step
    from gns_framework.model.rollout_guard import RolloutGuard
    from gns_framework.plugins import load_registry
    from gns_framework.training.optim import make_optimizer

    torch.manual_seed(0)
    scene = lattice_scene(particles, dim=dim)
    model = ModelSpec(graph_builder={"name": graph_builder})
    simulator = build_learned_simulator(scene.setup, scene.metadata, model, load_registry())
    batch = scene.batch
    guard = RolloutGuard(simulator.setup)
    kinematic = torch.zeros(0, dtype=torch.long)
    kinematic_next = torch.zeros(0, dim)
    mask = simulator.predicted_mask(batch.particle_type)
    noise = random_walk_noise(batch.position_sequence, 6.7e-4, torch.Generator().manual_seed(0))
    noise = noise * mask[:, None, None]

    def graph():
        with torch.no_grad():
            simulator.build_graph(batch.position_sequence, batch)

    def rollout():
        # As inside gns rollout: a fixed-capacity builder's overflow check comes every few steps, not here.
        with torch.inference_mode(), capacity_checks(simulator.graph_builder):
            rollout_step(simulator, guard, batch, kinematic, kinematic_next, "float32")

    def training():
        optimizer.zero_grad(set_to_none=True)
        prediction, target = simulator(batch, noise)
        masked_acceleration_loss(prediction, target, mask).backward()
        optimizer.step()
        scheduler.step()

    phases = [("graph_build", graph), ("rollout_step", rollout), ("training_step", training)]
    launches, read_backs = Launches(), []
    if simulator.graph_builder.fixed_capacity:
        phases.append(("captured_rollout_step", captured_rollout(simulator, guard, batch, kinematic, launches)))
    figures: dict = {"particles": particles, "dim": dim}
    with gpu_choices(launches, read_backs, triton):
        # Fused, as on an accelerator (make_optimizer decides by the parameters' device).
        optimizer, scheduler = make_optimizer(simulator.parameters(), OptimizerSpec(), total_steps=10, fused=True)
        with torch.no_grad():
            figures["edges"] = int(simulator.build_graph(batch.position_sequence, batch).num_edges)
        for name, step in phases:
            step()  # warm-up: lazily made constants, optimizer state
            operations, syncs = count(step, launches, read_backs)
            launching = {op: n for op, n in operations.items() if op not in NO_KERNEL}
            figures[name] = {
                "ops": sum(operations.values()),
                "launching": sum(launching.values()),
                "syncs": syncs,
                "top": Counter(launching).most_common(),
            }
    return figures


def captured_rollout(simulator, guard, batch, kinematic, launches: Launches):
    """One rollout step as ``gns rollout --capture`` runs it: inputs copied in, one replay, outputs copied out, the
    window advanced. A replay is one launch (``cuda_graph.replay``); what it replays is not dispatched by the host."""
    from torch.utils._python_dispatch import _disable_current_modes

    from gns_framework.model.captured_steps import CapturedSteps
    from gns_framework.model.history import advance_window
    from gns_framework.model.rollout import capacity_checks, rollout_step

    kinematic_next = torch.zeros(0, batch.position_sequence.shape[-1])
    one_step = lambda current, nxt: rollout_step(simulator, guard, current, kinematic, nxt, "float32")  # noqa: E731
    steps_of = CapturedSteps(one_step, batch, simulator.graph_builder)

    def step():
        with torch.inference_mode(), capacity_checks(simulator.graph_builder):
            fresh = steps_of.captured is None
            _, continued = steps_of(batch.position_sequence, None, kinematic_next)
            if fresh:  # count each later replay as the one launch it is on a GPU
                replay = steps_of.captured._replay

                def counted_replay():
                    with _disable_current_modes():
                        replay()
                    if launches.counter is not None:
                        launches.counter.operations["cuda_graph.replay"] += 1

                steps_of.captured._replay = counted_replay
            advance_window(batch.position_sequence, continued)

    return step


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--particles", type=int, default=10_000)
    parser.add_argument("--dim", type=int, choices=(2, 3), default=3)
    parser.add_argument("--top", type=int, default=15, help="operations listed per phase")
    parser.add_argument("--json", action="store_true", help="end with one JSON line")
    parser.add_argument("--chunked", action="store_true", help="the chunked edge block instead of the Triton one")
    parser.add_argument(
        "--graph-builder",
        default="radius",
        choices=("radius", "radius_fixed_capacity"),
        help="radius (exact size, read-backs) or radius_fixed_capacity (fixed-size buffers)",
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    figures = measure(args.particles, args.dim, triton=not args.chunked, graph_builder=args.graph_builder)
    print(
        f"{figures['particles']} particles, {figures['edges']} edges, {figures['dim']}D, {args.graph_builder}; "
        "GPU path on the CPU"
    )
    for phase in ("graph_build", "rollout_step", "training_step", "captured_rollout_step"):
        if phase not in figures:
            continue
        entry = figures[phase]
        top = ", ".join(f"{name} {n}" for name, n in entry["top"][: args.top])
        print(f"{phase:14s} ops={entry['ops']:5d} launching={entry['launching']:5d} syncs={entry['syncs']}  {top}")
    if args.json:
        summary = {
            "particles": figures["particles"],
            "edges": figures["edges"],
            "ops_per_graph_build": figures["graph_build"]["ops"],
            "launching_ops_per_graph_build": figures["graph_build"]["launching"],
            "launching_ops_per_rollout_step": figures["rollout_step"]["launching"],
            "launching_ops_per_training_step": figures["training_step"]["launching"],
            "syncs_per_graph_build": figures["graph_build"]["syncs"],
            "ops_per_rollout_step": figures["rollout_step"]["ops"],
            "syncs_per_rollout_step": figures["rollout_step"]["syncs"],
            "ops_per_training_step": figures["training_step"]["ops"],
            "syncs_per_training_step": figures["training_step"]["syncs"],
        }
        if "captured_rollout_step" in figures:
            summary["ops_per_captured_rollout_step"] = figures["captured_rollout_step"]["ops"]
            summary["syncs_per_captured_rollout_step"] = figures["captured_rollout_step"]["syncs"]
        print(json.dumps(summary))


if __name__ == "__main__":
    main()
