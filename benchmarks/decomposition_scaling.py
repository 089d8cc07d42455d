"""One scene split over P processes: time per step, memory per process and halo against P, and a projection to GPUs.

    python benchmarks/decomposition_scaling.py --particles 100000 --processes 1 2 4 [--aspect 8] [--dim 3]
        [--hops 5 --latent 64] [--halo positions latents] [--steps 5] [--train-steps 3] [--json]
        [--plot docs/images/decomposition_scaling.png] [--results docs/decomposition_results.json]

The scene is a 2D layer of water-like particles on a jittered lattice (about 20
neighbours each, benchmarks/lattice_scene.py's spacing and radius), ``--aspect``
times as wide as it is high, like a runout or a long channel. A randomly initialised
interaction network of ``--hops`` message-passing steps and ``--latent`` width (the
fast recipe's 5 x 64 by default) rolls it out for ``--steps`` steps and takes
``--train-steps`` training steps, decomposed into P pieces (``--cut``: slabs across the
width by default, or blocks by recursive bisection; :mod:`gns_framework.decomposition`),
under P gloo processes of one thread each, once with each kind of halo (``--halo``:
positions as deep as the receptive field, or latents one radius deep exchanged between
message-passing steps).

Per P and halo kind it prints: seconds per rollout step and per training step (the slowest process
sets the pace), the time spent in all-to-all exchanges, the halo fraction (halo particles
over owned ones), and the peak resident memory each process added beyond what it held
before the first step (the model, the scene and torch itself are not counted); ``--json`` and
``--results`` also give each process's absolute peak (``peak_rss_mb_per_process``: input, output
and torch included), the figure issue 50 compares against one process, and the size of its
shard of the output (``output_mb_per_process``). As ``gns rollout --partitions`` does, each
process reads its particles from the scene's memory-mapped file and writes its own shard.
On a machine with fewer cores than processes they share the cores (oversubscribed):
then times are not speed-ups, and the script says so; memory and halo are unaffected.

The projection for 8-64 GPUs (:func:`projection`) applies the same terms, the halo's share,
time per particle, exchange bytes and latency, with the per-particle times and bytes measured
on the lent H200 (docs/performance.md) and an InfiniBand link. The halo's share is counted on
the projected 3D lattice itself, cut into slabs and into blocks by the framework's own
partitions (:func:`lattice_halo_fractions`).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import statistics
import sys
import tempfile
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

SPACING = {2: 0.0058, 3: 0.0085}
"""Lattice spacing per dimension: about 20 neighbours within RADIUS in 2D and in 3D (benchmarks/lattice_scene.py)."""
RADIUS = 0.015
JITTER = 0.15
HISTORY = 6


def scene_sites(particles: int, aspect: float, dim: int = 2) -> tuple[int, ...]:
    """Lattice sites per axis: the first ``aspect`` times each other one, their product >= particles."""
    side = max(1, round((particles / aspect) ** (1 / dim)))
    return (math.ceil(particles / side ** (dim - 1)), *[side] * (dim - 1))


def lattice(particles: int, aspect: float, frames: int, dim: int = 2):
    """(frames, N, d) float32 positions of the jittered lattice in a slow random walk, and the box's bounds."""
    import numpy as np

    sites = scene_sites(particles, aspect, dim)
    rng = np.random.default_rng(0)
    axes = np.meshgrid(*[np.arange(n) for n in sites], indexing="ij")
    grid = np.stack(axes, -1).reshape(-1, dim)[:particles]
    spacing = SPACING[dim]
    start = (grid + rng.uniform(-JITTER, JITTER, grid.shape)) * spacing + 2 * spacing
    upper = [float(start[:, k].max()) + 2 * spacing for k in range(dim)]
    velocity = rng.normal(0.0, 2e-4, (frames, particles, dim)).astype(np.float32)
    position = (start[None].astype(np.float32) + np.cumsum(velocity, 0)).astype(np.float32)
    return position, tuple((0.0, upper[k]) for k in range(dim))


def model(bounds, hops: int, latent: int, frames: int, dim: int = 2):
    """The randomly initialised simulator of the scene in ``bounds`` (the same in every process), and its metadata."""
    from gns_framework.assembly.learned import build_learned_simulator
    from gns_framework.config.recipe import ModelSpec
    from gns_framework.contracts import ModelSetup
    from gns_framework.data.metadata import DatasetMetadata
    from gns_framework.plugins import load_registry

    scene = ModelSetup(dim=dim, bounds=bounds, connectivity_radius=RADIUS, particle_types=(5,), history=HISTORY)
    metadata = DatasetMetadata(
        bounds=[list(b) for b in bounds],
        sequence_length=frames,
        default_connectivity_radius=RADIUS,
        dim=dim,
        dt=0.0025,
        vel_mean=[0.0] * dim,
        vel_std=[2e-4] * dim,
        acc_mean=[0.0] * dim,
        acc_std=[2e-4] * dim,
    )
    spec = ModelSpec(
        latent_size=latent,
        mlp_hidden_size=latent,
        mlp_hidden_layers=2,
        processor={"name": "interaction_network", "message_passing_steps": hops},
    )
    torch.manual_seed(0)
    return build_learned_simulator(scene, metadata, spec, load_registry()), metadata


def _resident_mb() -> float:
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3  # KiB on Linux


def worker(rank: int, world: int, port: int, out: str, config: dict) -> None:
    """Measure one process of a P-process run; writes ``rank<r>.json``."""
    import numpy as np
    import torch.distributed as dist

    from gns_framework.data.trajectory import Trajectory
    from gns_framework.decomposition.rollout import sharded_rollout
    from gns_framework.io.sharded_rollout import shard_name
    from gns_framework.training.distributed import processes_from_environment, start, stop

    os.environ.update(
        MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port), RANK=str(rank), WORLD_SIZE=str(world), LOCAL_RANK=str(rank)
    )
    torch.set_num_threads(1)
    processes = processes_from_environment()
    start(processes, torch.device("cpu"))
    exchanged = [0.0]
    calls = {"count": 0, "bytes": 0}
    if processes.distributed:
        plain = dist.all_to_all_single

        def timed(output, input, *args, **kwargs):
            began = time.perf_counter()
            result = plain(output, input, *args, **kwargs)
            exchanged[0] += time.perf_counter() - began
            calls["count"] += 1
            calls["bytes"] += input.numel() * input.element_size()
            return result

        dist.all_to_all_single = timed
    try:
        steps, train_steps = config["steps"], config["train_steps"]
        frames, dim = HISTORY + steps + 1, config["dim"]
        simulator, metadata = model(tuple(map(tuple, config["bounds"])), config["hops"], config["latent"], frames, dim)
        # The scene is a memory-mapped file, as a dataset's positions are: a process reads only what it touches.
        position = np.load(Path(out) / "position.npy", mmap_mode="r")
        trajectory = Trajectory(position, np.full(position.shape[1], 5, dtype=np.int64), key="layer")
        before = _resident_mb()
        halo = config["halo"]
        cut, axis = config["cut"], (0 if config["cut"] == "slabs" else None)
        options = dict(halo=halo, axis=axis, cut=cut)
        # Warm-up: allocations, kernels. Then the rollout as gns rollout --partitions runs it: each process writes
        # its own shard of the output.
        sharded_rollout(simulator, trajectory, processes, Path(out) / "warm-up", metadata, steps=1, **options)
        exchanged[0] = 0.0
        calls.update(count=0, bytes=0)
        processes.barrier()
        began = time.perf_counter()
        folder = Path(out) / "rollout"
        _, stats = sharded_rollout(simulator, trajectory, processes, folder, metadata, steps=steps, **options)
        rollout_seconds = (time.perf_counter() - began) / steps
        output_mb = (folder / shard_name(rank)).stat().st_size / 1e6
        rollout_exchange = exchanged[0] / steps
        rollout_calls = dict(calls)
        rollout_peak_rss = _peak_mb()  # before training, which needs several times a rollout's memory
        rollout_peak = rollout_peak_rss - before
        training = _training(simulator, trajectory, processes, halo, axis, cut, train_steps, exchanged, before)
        result = {
            "rank": rank,
            "rollout_seconds": rollout_seconds,
            "rollout_exchange_seconds": rollout_exchange,
            "rollout_exchange_calls": rollout_calls["count"],
            "rollout_exchange_bytes": rollout_calls["bytes"],
            "rollout_peak_mb": rollout_peak,
            "rollout_peak_rss_mb": rollout_peak_rss,
            "output_mb": output_mb,
            **training,
            "halo_fraction": stats.halo_fraction,
            "partition": stats.partition.describe(),
        }
        (Path(out) / f"rank{rank}.json").write_text(json.dumps(result))
    finally:
        stop()


def _training(simulator, trajectory, processes, halo, axis, cut, train_steps: int, exchanged, before: float) -> dict:
    """The median seconds of ``train_steps`` decomposed training steps (after one warm-up), the time in exchanges,
    and the peak memory added; NaN without training steps (``--train-steps 0``: a rollout alone)."""
    from gns_framework.data.batch import window
    from gns_framework.decomposition.halo import partition_for
    from gns_framework.decomposition.training_step import owned_share, partitioned_gradients

    if train_steps == 0:
        return {"owned": None, "train_seconds": math.nan, "train_exchange_seconds": math.nan, "train_peak_mb": math.nan}
    simulator.train()
    batch = window(trajectory, 0, HISTORY, with_target=True)
    noise = torch.zeros_like(batch.position_sequence)
    partition, kind = partition_for(simulator, batch.position_sequence[:, -1], processes.world_size, halo, axis, cut)
    owned = owned_share(batch, noise, partition, processes.rank)
    times, train_exchange = [], []
    for _ in range(train_steps + 1):
        simulator.zero_grad(set_to_none=True)
        exchanged[0] = 0.0
        processes.barrier()
        began = time.perf_counter()
        partitioned_gradients(simulator, owned, batch, partition, processes, kind)
        times.append(time.perf_counter() - began)
        train_exchange.append(exchanged[0])
    return {
        "owned": owned.count,
        "train_seconds": statistics.median(times[1:]),
        "train_exchange_seconds": statistics.median(train_exchange[1:]),
        "train_peak_mb": _peak_mb() - before,
    }


def _free_port() -> int:
    import socket

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def measure(processes: int, config: dict) -> dict:
    import numpy as np

    with tempfile.TemporaryDirectory() as out:
        frames = HISTORY + config["steps"] + 1
        position, bounds = lattice(config["particles"], config["aspect"], frames, config["dim"])
        np.save(Path(out) / "position.npy", position)
        del position
        config = dict(config, bounds=bounds)
        torch.multiprocessing.spawn(worker, args=(processes, _free_port(), out, config), nprocs=processes)
        ranks = [json.loads((Path(out) / f"rank{r}.json").read_text()) for r in range(processes)]
    return {
        "processes": processes,
        "rollout_seconds": max(r["rollout_seconds"] for r in ranks),
        "rollout_exchange_seconds": max(r["rollout_exchange_seconds"] for r in ranks),
        "seconds_per_exchange": max(
            r["rollout_exchange_seconds"] * config["steps"] / max(r["rollout_exchange_calls"], 1) for r in ranks
        ),
        "exchange_bytes_per_second": sum(r["rollout_exchange_bytes"] for r in ranks)
        / max(sum(r["rollout_exchange_seconds"] * config["steps"] for r in ranks), 1e-9),
        "train_seconds": max(r["train_seconds"] for r in ranks),
        "train_exchange_seconds": max(r["train_exchange_seconds"] for r in ranks),
        "rollout_peak_mb_per_process": max(r["rollout_peak_mb"] for r in ranks),
        # The record (docs/decomposition_results.json): absolute peak resident memory, input included.
        "particles": config["particles"],
        "dim": config["dim"],
        "peak_rss_mb_per_process": max(r["rollout_peak_rss_mb"] for r in ranks),
        "output_mb_per_process": max(r["output_mb"] for r in ranks),
        "seconds_per_step": max(r["rollout_seconds"] for r in ranks),
        "train_peak_mb_per_process": max(r["train_peak_mb"] for r in ranks),
        "halo_fraction": ranks[0]["halo_fraction"],
        "partition": ranks[0]["partition"],
        "owned_per_process": [r["owned"] for r in ranks],
    }


H200 = {
    # The paper's model (10 x 128) on the 3D lattice, docs/performance.md (lent H200, 2026-12-04).
    "rollout_seconds_per_particle": 3.31 / 1e6,  # bfloat16, 1M particles
    "train_seconds_per_particle": 12.4 / 1e6,  # bfloat16 + recomputed activations, 1M particles
    "train_bytes_per_particle": 118.9e9 / 1e6,
    "memory_bytes": 139e9,
    "parameters": 1.6e6,
}
GPU_RESULTS = Path(__file__).resolve().parents[1] / "docs" / "gpu_results.json"


def gpu_terms(results: Path = GPU_RESULTS) -> tuple[dict[str, float], str]:
    """The per-particle step times the projection scales, and where they come from: the newest device run in
    ``results`` (benchmarks/gpu_results.py's records) that timed a rollout and a training step at the same
    particle count (its largest), else the first H200 run (:data:`H200`). Memory per particle stays the first
    run's, which a record does not hold."""
    runs = json.loads(results.read_text()) if results.is_file() else []
    for run in reversed(runs):
        timed = set(run.get("rollout_ms") or {}) & set(run.get("training_ms") or {})
        if timed:
            n = max(timed, key=int)
            terms = dict(H200)
            terms["rollout_seconds_per_particle"] = run["rollout_ms"][n] / 1e3 / int(n)
            terms["train_seconds_per_particle"] = run["training_ms"][n] / 1e3 / int(n)
            return terms, f"{run['device']}, {run['date']} ({run['commit'][:7]}), {int(n):,} particles, {results.name}"
    return dict(H200), "H200, 2026-12-04, 1,000,000 particles (docs/performance.md)"


LINK = {"latency_s": 20e-6, "bytes_per_s": 25e9}
"""Between nodes: InfiniBand NDR (200 Gb/s, ~25 GB/s) and ~20 us per exchange; NVLink within a node is faster."""
RADIUS_IN_SITES_3D = 0.015 / 0.0085
"""The 3D lattice's connectivity radius in lattice spacings (benchmarks/lattice_scene.py)."""


def lattice_halo_fractions(particles: float, aspect: float, depth: float, gpus: list[int], cut: str) -> list[float]:
    """The halo's share of the particles (halo particle copies over particles) of a 3D lattice split into P pieces.

    The lattice (unit spacing) is ``aspect`` times as long as its square cross-section and
    holds about ``particles`` sites; ``depth`` is the halo's depth in lattice spacings. The
    pieces are the framework's own (:func:`gns_framework.decomposition.partition.balanced_partition`,
    ``cut`` slabs or blocks), counted in chunks so that 10M sites fit in memory.
    """
    from gns_framework.decomposition.partition import balanced_partition, halo_count

    side = max(1, round((particles / aspect) ** (1 / 3)))
    length = max(1, round(particles / side**2))
    axes = [torch.arange(n, dtype=torch.float32) for n in (length, side, side)]
    position = torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1).reshape(-1, 3)
    shares = []
    for p in gpus:
        partition = balanced_partition(position, p, depth, cut)  # type: ignore[arg-type]
        halo = halo_count(partition, position)
        shares.append(halo / position.shape[0])
    return shares


def projection(
    particles: float, aspect: float, hops: int, gpus: list[int], cut: str = "slabs", terms: dict | None = None
) -> list[dict]:
    """Step time and memory per GPU of a 3D scene split into P pieces (``cut``: slabs or blocks) on P H200s.

    The scene is a lattice ``aspect`` times as long as its square cross-section. Each piece
    holds N / P particles and a halo ``hops x R`` deep (positions) or ``R`` deep (latents),
    whose share h of the particles is counted on the lattice (:func:`lattice_halo_fractions`).
    A step costs the GPU's time per particle for N / P (1 + h) particles, plus the exchanges:
    the halo's positions (C x 3 float32 each), the predicted frame gathered on rank 0
    (rollout), the gradients' all-reduce (training; ring: twice the parameters' bytes), at
    :data:`LINK`'s rate; with a halo of latents, 128 bfloat16 per halo particle after each hop. ``terms``: the
    GPU's per-particle figures (:func:`gpu_terms`; default: the first H200 run's).
    """
    gpu = H200 if terms is None else terms
    deep = lattice_halo_fractions(particles, aspect, hops * RADIUS_IN_SITES_3D, gpus, cut)
    shallow = lattice_halo_fractions(particles, aspect, RADIUS_IN_SITES_3D, gpus, cut)
    rows = []
    for p, halo, thin in zip(gpus, deep, shallow, strict=True):
        per_gpu = particles / p * (1 + halo)
        halo_bytes = particles / p * halo * HISTORY * 3 * 4
        rollout_link = 3 * LINK["latency_s"] + (halo_bytes + particles / p * 3 * 4) / LINK["bytes_per_s"]
        train_link = 2 * LINK["latency_s"] + (halo_bytes + 2 * 4 * gpu["parameters"]) / LINK["bytes_per_s"]
        train_bytes = per_gpu * gpu["train_bytes_per_particle"]
        ideal = particles / p * gpu["train_seconds_per_particle"]
        train_seconds = per_gpu * gpu["train_seconds_per_particle"] + train_link
        latent_link = hops * (LINK["latency_s"] + particles / p * thin * 128 * 2 / LINK["bytes_per_s"])
        per_gpu_shallow = particles / p * (1 + thin)
        rows.append(
            {
                "gpus": p,
                "cut": cut,
                "halo_fraction": halo,
                "halo_fraction_latents": thin,
                "rollout_seconds": per_gpu * gpu["rollout_seconds_per_particle"] + rollout_link,
                "train_seconds": train_seconds,
                "train_efficiency": ideal / train_seconds,
                "rollout_seconds_latents": per_gpu_shallow * gpu["rollout_seconds_per_particle"]
                + rollout_link
                + latent_link,
                "train_seconds_latents": per_gpu_shallow * gpu["train_seconds_per_particle"]
                + train_link
                + 2 * latent_link,
                "train_gb_per_gpu": train_bytes / 1e9,
                "train_gb_per_gpu_latents": per_gpu_shallow * gpu["train_bytes_per_particle"] / 1e9,
                "fits": train_bytes < gpu["memory_bytes"],
            }
        )
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--particles", type=int, default=100_000)
    parser.add_argument("--processes", type=int, nargs="+", default=[1, 2, 4])
    parser.add_argument("--aspect", type=float, default=8.0, help="scene width / height (slabs cut the width)")
    parser.add_argument("--hops", type=int, default=5, help="message-passing steps (halo = hops x radius)")
    parser.add_argument("--latent", type=int, default=64)
    parser.add_argument(
        "--halo", nargs="+", default=["positions", "latents"], choices=["positions", "latents"], help="halo kinds"
    )
    parser.add_argument(
        "--cut",
        default="slabs",
        choices=["slabs", "blocks", "auto"],
        help="how the measured scene is split: slabs across its width, blocks by recursive bisection, or auto",
    )
    parser.add_argument("--steps", type=int, default=5, help="rollout steps timed")
    parser.add_argument(
        "--train-steps", type=int, default=3, help="training steps timed (after one warm-up); 0: the rollout alone"
    )
    parser.add_argument(
        "--project-particles", type=float, default=1e7, help="the 3D scene of the GPU projection (default 10M)"
    )
    parser.add_argument("--project-aspect", type=float, default=8.0, help="its length / cross-section side")
    parser.add_argument("--project-gpus", type=int, nargs="+", default=[1, 8, 16, 32, 64])
    parser.add_argument("--dim", type=int, choices=(2, 3), default=2, help="a 2D layer or a 3D block of particles")
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--plot", type=Path, help="write a figure of time and memory per process against P")
    parser.add_argument(
        "--results",
        type=Path,
        help="append each measured run (particles, processes, peak_rss_mb_per_process, seconds_per_step, ...) to "
        "this JSON list (docs/decomposition_results.json)",
    )
    args = parser.parse_args(argv)
    cores = len(os.sched_getaffinity(0))
    keys = ("particles", "aspect", "hops", "latent", "steps", "train_steps", "cut", "dim")
    config = {k: getattr(args, k) for k in keys}
    sites = scene_sites(args.particles, args.aspect, args.dim)
    print(
        f"scene: {args.particles} particles, {' x '.join(map(str, sites))} lattice sites, halo depth {args.hops} x R "
        f"= {args.hops * RADIUS / SPACING[args.dim]:.1f} sites; {cores} core(s)"
    )
    rows = []
    for p in args.processes:
        for halo in args.halo if p > 1 else ["positions"]:
            row = measure(p, dict(config, halo=halo))
            row["halo"], row["oversubscribed"] = halo, p > cores
            rows.append(row)
            note = " (oversubscribed: processes share cores)" if row["oversubscribed"] else ""
            print(
                f"P={p} ({row['partition']}) halo of {halo if p > 1 else '-'}: rollout step "
                f"{row['rollout_seconds']:.3f} s "
                f"(exchanges {row['rollout_exchange_seconds']:.3f} s), training step {row['train_seconds']:.3f} s "
                f"(exchanges {row['train_exchange_seconds']:.3f} s), halo {row['halo_fraction']:.1%} of the "
                f"particles, peak added memory per process: rollout {row['rollout_peak_mb_per_process']:.0f} MB, "
                f"training {row['train_peak_mb_per_process']:.0f} MB{note}",
                flush=True,
            )
    terms, source = gpu_terms()
    print(
        f"\nprojection: the paper's model (10 x 128, bfloat16, recomputed activations) on a 3D scene of "
        f"{args.project_particles:.3g} particles, {args.project_aspect:g}x as long as wide, on P GPUs "
        f"timed as in {source}:"
    )
    projected = []
    for cut in ("slabs", "blocks"):
        rows_of_cut = projection(args.project_particles, args.project_aspect, 10, args.project_gpus, cut, terms)
        projected += rows_of_cut
        for row in rows_of_cut:
            print(
                f"  {cut:6s} P={row['gpus']:3d}: halo {row['halo_fraction']:6.1%} deep / "
                f"{row['halo_fraction_latents']:5.1%} one radius; halo of positions: rollout step "
                f"{row['rollout_seconds']:.3f} s, training step {row['train_seconds']:.3f} s (efficiency "
                f"{row['train_efficiency']:.0%}), {row['train_gb_per_gpu']:.0f} GB per GPU"
                f"{'' if row['fits'] else ' (does not fit)'}; halo of latents: rollout "
                f"{row['rollout_seconds_latents']:.3f} s, "
                f"training {row['train_seconds_latents']:.3f} s, {row['train_gb_per_gpu_latents']:.0f} GB per GPU",
                flush=True,
            )
    if args.plot:
        plot(rows, args.plot)
    if args.results:
        append_results(args.results, rows, config)
    if args.json:
        print(json.dumps({"config": config, "cores": cores, "rows": rows, "projection": projected}))
    return 0


def append_results(path: Path, rows: list[dict], config: dict) -> None:
    """Each measured run appended to the JSON list at ``path`` (made when absent), with the date and the commit."""
    import datetime
    import subprocess

    commit = subprocess.run(
        ["git", "-C", str(Path(__file__).resolve().parents[1]), "rev-parse", "--short", "HEAD"],
        capture_output=True,
        text=True,
    ).stdout.strip()
    runs = json.loads(path.read_text()) if path.exists() else []
    if not isinstance(runs, list):
        raise SystemExit(f"decomposition_scaling.py: {path} holds no JSON list of runs")
    stamp = {"date": datetime.date.today().isoformat(), "commit": commit or "unknown", "cores": os.cpu_count()}
    runs += [{**stamp, **{k: config[k] for k in ("hops", "latent", "cut")}, **row} for row in rows]
    path.write_text(json.dumps(runs, indent=1) + "\n")
    print(f"decomposition_scaling.py: {len(runs)} run(s) in {path}")


def plot(rows: list[dict], path: Path) -> None:
    """Time per step and peak added memory per process against P, one line per halo kind (P = 1 in both)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, (time_axis, memory_axis) = plt.subplots(1, 2, figsize=(10, 4))
    alone = [r for r in rows if r["processes"] == 1]
    for halo, marker in (("positions", "o"), ("latents", "s")):
        kind = alone + [r for r in rows if r["processes"] > 1 and r["halo"] == halo]
        if len(kind) == len(alone):
            continue
        p = [r["processes"] for r in kind]
        time_axis.plot(p, [r["rollout_seconds"] for r in kind], marker + "-", label=f"rollout, halo of {halo}")
        time_axis.plot(p, [r["train_seconds"] for r in kind], marker + "--", label=f"training, halo of {halo}")
        memory_axis.plot(p, [r["rollout_peak_mb_per_process"] for r in kind], marker + "-", label=f"rollout, {halo}")
        memory_axis.plot(p, [r["train_peak_mb_per_process"] for r in kind], marker + "--", label=f"training, {halo}")
    ticks = sorted({r["processes"] for r in rows})
    time_axis.set(xlabel="processes P", ylabel="seconds per step (slowest process)", xticks=ticks)
    memory_axis.set(xlabel="processes P", ylabel="peak added memory per process (MB)", xticks=ticks)
    time_axis.legend(fontsize=8)
    memory_axis.legend(fontsize=8)
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=120)


if __name__ == "__main__":
    sys.exit(main())
