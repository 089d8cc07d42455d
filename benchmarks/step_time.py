"""Step time of the reference model on the lattice benchmark scene.

Usage:
    python benchmarks/step_time.py --particles N [--dim 2|3] [--repeat R] [--json] [--peer [--peer-allocator ours]]
                                   [--precision bfloat16]
    python benchmarks/step_time.py [--quick] [--json]  # the suite, one fresh process per scene, as a table

One scene: median wall time of one training step (noise, forward, loss, backward,
Adam), one rollout step (graph, features, model, integration, history shift) and
the neighbour search alone, after warm-up runs; peak resident memory after the
inference cases and after the training cases (``ru_maxrss``); and the efficiency
ratio: the FLOP/s of the model's dense work divided by the FLOP/s torch.mm reaches
on an (E, 128) x (128, 128) product in the same run. Cases are interleaved
repeat by repeat, so load from other processes hits them alike. ``--peer`` also
times the reference-style restatement (benchmarks/reference_style.py) with the
same parameters, interleaved step by step, and reports the speed-up over it. The
peer runs in a child process with glibc's default allocator, as the reference
does; ``--peer-allocator ours`` gives it our setting (gns_framework/runtime/allocator.py)
instead, which isolates what the allocator alone is worth.

The scene is benchmarks/lattice_scene.py: one example, jittered lattice, radius
0.015, ~20 neighbours per particle, WaterDrop statistics, 9 particle types; the
model is the paper's (latent 128, two hidden layers of 128, 10 steps).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from lattice_scene import lattice_scene
from model_flops import forward_flops

from gns_framework.assembly.learned import build_learned_simulator
from gns_framework.config.recipe import ModelSpec, OptimizerSpec
from gns_framework.model.loss import masked_acceleration_loss
from gns_framework.model.noise import random_walk_noise
from gns_framework.plugins import load_registry
from gns_framework.runtime.activation_memory import recompute_activations, set_recompute_activations
from gns_framework.runtime.allocator import keep_freed_memory
from gns_framework.runtime.precision import PRECISIONS, autocast
from gns_framework.training.optim import make_optimizer

SUITE = [(992, 2), (3969, 2), (10000, 2), (100000, 2), (8000, 3)]
LARGE = 20_000
"""Scenes above this many particles: 3 repeats, no training step unless asked, and no peer (its
training memory, ~42 KB per edge, does not fit)."""


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def interleaved(cases: dict, warmup: int, repeat: int) -> dict[str, float]:
    """Median seconds per case, the cases taking turns within every repeat."""
    seconds: dict[str, list[float]] = {name: [] for name in cases}
    for index in range(warmup + repeat):
        for name, fn in cases.items():
            start = time.perf_counter()
            fn()
            if index >= warmup:
                seconds[name].append(time.perf_counter() - start)
    return {name: statistics.median(values) for name, values in seconds.items()}


class Stepper:
    """One rollout step and one training step of a simulator on a fixed window."""

    def __init__(self, simulator, batch, seed: int = 0, precision: str = "float32"):
        self.simulator = simulator
        self.precision = precision
        self.batch = batch
        spec = OptimizerSpec()  # the reference schedule: exponential, independent of the run length
        self.optimizer, self.scheduler = make_optimizer(simulator.parameters(), spec, total_steps=1)
        self.generator = torch.Generator().manual_seed(seed)
        self.mask = simulator.predicted_mask(batch.particle_type)

    def rollout_step(self) -> None:
        with torch.inference_mode(), autocast(self.precision, "cpu"):
            next_position = self.simulator.predict_next_position(self.batch)
            torch.cat([self.batch.position_sequence[:, 1:], next_position[:, None]], dim=1)

    def train_step(self) -> None:
        noise = random_walk_noise(self.batch.position_sequence, 6.7e-4, self.generator) * self.mask[:, None, None]
        with autocast(self.precision, "cpu"):
            prediction, target = self.simulator(self.batch, noise)
        loss = masked_acceleration_loss(prediction.to(target.dtype), target, self.mask)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        self.scheduler.step()


def benchmark_model(particles: int, dim: int):
    """The scene and the paper's model on it, with parameters that depend only on the seed."""
    scene = lattice_scene(particles, dim)
    torch.manual_seed(0)
    return scene, build_learned_simulator(scene.setup, scene.metadata, ModelSpec(), load_registry())


class PeerProcess:
    """The reference-style peer in a child process, stepped on request.

    A child has its own allocator setting: glibc's default, as the reference runs,
    while this process keeps freed memory. Built from the same seed, the peer
    computes the same function as our model; each call blocks until its step is done.
    """

    def __init__(self, particles: int, dim: int, threads: int, allocator: str):
        command = [
            sys.executable,
            __file__,
            "--serve-peer",
            "--particles",
            str(particles),
            "--dim",
            str(dim),
            "--threads",
            str(threads),
        ]
        environment = dict(os.environ, GNS_KEEP_FREED_MEMORY="1" if allocator == "ours" else "0")
        self.process = subprocess.Popen(
            command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=environment
        )
        self.ask("ready")

    def ask(self, command: str) -> str:
        self.process.stdin.write(command + "\n")
        self.process.stdin.flush()
        reply = self.process.stdout.readline()
        if not reply:
            raise RuntimeError(f"the peer process exited with status {self.process.wait()} on '{command}'")
        return reply.strip()

    def rollout_step(self) -> None:
        self.ask("rollout")

    def train_step(self) -> None:
        self.ask("train")

    def peak_rss_mb(self) -> float:
        return float(self.ask("rss"))

    def close(self) -> None:
        self.process.stdin.close()
        self.process.wait()


def serve_peer(particles: int, dim: int) -> None:
    """The child of :class:`PeerProcess`: one reply line per command line on stdin."""
    from reference_style import reference_style

    keep_freed_memory()
    scene, simulator = benchmark_model(particles, dim)
    peer = Stepper(reference_style(simulator), scene.batch)
    actions = {"ready": lambda: None, "rollout": peer.rollout_step, "train": peer.train_step}
    for line in sys.stdin:
        command = line.strip()
        reply = peak_rss_mb() if command == "rss" else actions[command]()
        print("ok" if reply is None else reply, flush=True)


def measure(particles: int, dim: int, repeat: int, warmup: int, peer: str | None, train: bool, precision: str) -> dict:
    """Every figure of one scene; ``peer`` is None or the peer's allocator ("glibc" or "ours")."""
    tuned = keep_freed_memory()
    load_before = os.getloadavg()[0]
    scene, simulator = benchmark_model(particles, dim)
    batch = scene.batch
    position = batch.position_sequence[:, -1]
    graph = simulator.build_graph(batch.position_sequence, batch)
    edges = graph.num_edges
    ours = Stepper(simulator, batch, precision=precision)
    steppers = {"": ours}
    if peer:
        peer_process = PeerProcess(particles, dim, torch.get_num_threads(), peer)
        steppers["peer_"] = peer_process

    latent = simulator.processor.steps[0].latent
    hidden = simulator.processor.steps[0].edge_mlp.mlp.linears[1].in_features
    mm_a, mm_b = torch.randn(edges, latent), torch.randn(latent, hidden)
    mm_out = torch.empty(edges, hidden)

    cases = {
        "neighbour_search_s": lambda: simulator.graph_builder.build(position, batch.batch, 1),
        "mm_s": lambda: torch.mm(mm_a, mm_b, out=mm_out),
    }
    cases.update({f"{prefix}rollout_step_s": stepper.rollout_step for prefix, stepper in steppers.items()})
    result = interleaved(cases, warmup, repeat)
    rss_inference = peak_rss_mb()
    if peer:
        result["peer_peak_rss_inference_mb"] = peer_process.peak_rss_mb()
    if train:
        result.update(
            interleaved({f"{prefix}train_step_s": s.train_step for prefix, s in steppers.items()}, warmup, repeat)
        )
    if peer:
        result["peer_peak_rss_mb"] = peer_process.peak_rss_mb()
        peer_process.close()

    mm_flops = 2 * edges * latent * hidden / result.pop("mm_s")
    flops = forward_flops(simulator, particles, edges)
    figures = {
        "particles": particles,
        "dim": dim,
        "edges": edges,
        "mean_neighbours": edges / particles - 1,
        "threads": torch.get_num_threads(),
        "precision": precision,
        "repeat": repeat,
        "warmup": warmup,
        **result,
        "rollout_particles_per_s": particles / result["rollout_step_s"],
        "rollout_edges_per_s": edges / result["rollout_step_s"],
        "neighbour_search_per_particle_us": 1e6 * result["neighbour_search_s"] / particles,
        "rollout_per_particle_us": 1e6 * result["rollout_step_s"] / particles,
        "peak_rss_inference_mb": rss_inference,
        "peak_rss_mb": peak_rss_mb(),
        "mm_gflops": mm_flops / 1e9,
        "model_gflop_per_forward": flops / 1e9,
        "efficiency": flops / result["rollout_step_s"] / mm_flops,
        "keep_freed_memory": tuned,
        "recompute_activations": recompute_activations(),
        "load_before": load_before,
        "load_after": os.getloadavg()[0],
    }
    if train:
        figures["train_particles_per_s"] = particles / result["train_step_s"]
        figures["train_efficiency"] = 3 * flops / result["train_step_s"] / mm_flops
    if peer:
        figures["peer_allocator"] = peer
        figures["peer_rollout_speedup"] = result["peer_rollout_step_s"] / result["rollout_step_s"]
        peer_flops = forward_flops(simulator, particles, edges, split_first_layer=False)
        figures["peer_efficiency"] = peer_flops / result["peer_rollout_step_s"] / mm_flops
        if train:
            figures["peer_train_speedup"] = result["peer_train_step_s"] / result["train_step_s"]
    return figures


def run_suite(args) -> list[dict]:
    """Each scene in a fresh process, so peak memory and allocator state are its own."""
    rows = []
    for particles, dim in SUITE:
        large = particles > LARGE
        command = [
            sys.executable,
            __file__,
            "--particles",
            str(particles),
            "--dim",
            str(dim),
            "--json",
            "--threads",
            str(args.threads),
            *(["--recompute"] if args.recompute else []),
            "--precision",
            args.precision,
            "--repeat",
            str(3 if large or args.quick else args.repeat),
            "--warmup",
            str(1 if large or args.quick else args.warmup),
        ]
        if large and not args.train_large:
            command.append("--no-train")
        if not large and not args.no_peer:
            command += ["--peer", "--peer-allocator", args.peer_allocator]
        output = subprocess.run(command, check=True, capture_output=True, text=True).stdout
        rows.append(json.loads(output.strip().splitlines()[-1]))
        print(format_row(rows[-1]), file=sys.stderr, flush=True)
    return rows


HEADER = (
    "| scene | particles | edges (incl. self) | mean neighbours | training step | rollout step | neighbour search "
    "| rollout particles/s | rollout edges/s | peak RSS inference / training | efficiency (rollout / training) "
    "| speed-up vs peer (training / rollout) |\n|" + "---|" * 12
)


def format_row(r: dict) -> str:
    train = f"{r['train_step_s']:.3f} s" if "train_step_s" in r else "n/a"
    train_eff = f"{r['train_efficiency']:.2f}" if "train_efficiency" in r else "n/a"
    rss_train = f"{r['peak_rss_mb'] / 1024:.2f} GB" if "train_step_s" in r else "\N{EN DASH} GB"
    peer = "n/a"
    if "peer_rollout_speedup" in r:
        peer_train = f"{r['peer_train_speedup']:.1f}x" if "peer_train_speedup" in r else "n/a"
        peer = f"{peer_train} / {r['peer_rollout_speedup']:.1f}x"
    scene = f"{r['dim']}D" if r.get("precision", "float32") == "float32" else f"{r['dim']}D, {r['precision']}"
    return (
        f"| {scene} | {r['particles']:,} | {r['edges']:,} | {r['mean_neighbours']:.1f} | {train} "
        f"| {r['rollout_step_s']:.3f} s | {1e3 * r['neighbour_search_s']:.1f} ms | {r['rollout_particles_per_s']:,.0f} "
        f"| {r['rollout_edges_per_s']:.3g} | {r['peak_rss_inference_mb'] / 1024:.2f} / {rss_train} "
        f"| {r['efficiency']:.2f} / {train_eff} | {peer} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--particles", type=int, help="one scene of about this many particles (default: the suite)")
    parser.add_argument("--dim", type=int, choices=(2, 3), default=2)
    parser.add_argument("--repeat", type=int, default=10)
    parser.add_argument("--warmup", type=int, default=3)
    parser.add_argument("--threads", type=int, default=2, help="torch intra-op threads")
    parser.add_argument("--json", action="store_true", help="print one JSON object (the suite: a list of them)")
    parser.add_argument("--peer", action="store_true", help="also time the reference-style peer, interleaved")
    parser.add_argument(
        "--peer-allocator",
        choices=("glibc", "ours"),
        default="glibc",
        help="the peer's allocator: glibc's default, as the reference runs (default), or our setting",
    )
    parser.add_argument("--no-train", action="store_true", help="skip the training step")
    parser.add_argument("--recompute", action="store_true", help="training.recompute_activations: true")
    parser.add_argument(
        "--precision", choices=PRECISIONS, default="float32", help="our model's product dtype (the peer stays float32)"
    )
    parser.add_argument("--quick", action="store_true", help="suite: 3 repeats after 1 warm-up")
    parser.add_argument("--no-peer", action="store_true", help="suite: never time the peer")
    parser.add_argument("--train-large", action="store_true", help="suite: time training at 100k particles too")
    parser.add_argument("--serve-peer", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    set_recompute_activations(args.recompute)
    if args.particles is None:
        print(f"load average before: {os.getloadavg()}", file=sys.stderr)
        rows = run_suite(args)
        if args.json:
            print(json.dumps(rows))
            return
        print(HEADER)
        print("\n".join(format_row(r) for r in rows))
        print(f"load average after: {os.getloadavg()}")
        return
    if args.serve_peer:
        serve_peer(args.particles, args.dim)
        return
    peer = args.peer_allocator if args.peer else None
    figures = measure(args.particles, args.dim, args.repeat, args.warmup, peer, not args.no_train, args.precision)
    print(json.dumps(figures) if args.json else HEADER + "\n" + format_row(figures))


if __name__ == "__main__":
    main()
