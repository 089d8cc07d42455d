"""Peak memory per training process under DDP: every trajectory kept (``dataset.memory: all``) against a few
(``windows``).

Writes a synthetic dataset in the safe layout (random walks of particles on a
lattice: the values do not matter to memory), several times larger than one
process's share at the largest process count, then for each process count P and
each mode trains a small model for a few steps under ``torchrun --nproc-per-node P``
(gloo, CPU, one thread per process), then reads every train trajectory once, as the
windows of a whole epoch would, and prints each rank's peak resident set size
(``ru_maxrss``: anonymous memory and the file pages it mapped and touched).

    python benchmarks/data_memory.py --megabytes 1500 --processes 1 2 4 [--json]

On a machine with fewer cores than processes the ranks share them (oversubscribed):
memory is what this measures, not time.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

PARTICLES = 2000
FRAMES = 100
SPACING = 0.01


def write_dataset(path: Path, megabytes: float, seed: int = 0) -> int:
    """A safe-layout dataset whose train split holds about ``megabytes`` of positions; returns its trajectories."""
    from gns_framework.data.metadata import DatasetMetadata, compute_statistics
    from gns_framework.plugins import load_registry

    registry = load_registry()
    sand = registry.get("material", "sand").particle_type
    per_trajectory = FRAMES * PARTICLES * 2 * 4 / 1e6
    count = max(2, round(megabytes / per_trajectory))
    rng = np.random.default_rng(seed)
    side = int(np.ceil(np.sqrt(PARTICLES)))
    lattice = np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2)[:PARTICLES] * SPACING + 0.2

    def trajectory(key: str):
        from gns_framework.data.trajectory import Trajectory

        steps = rng.normal(scale=SPACING * 0.02, size=(FRAMES, PARTICLES, 2)).astype(np.float32)
        position = (lattice[None] + np.cumsum(steps, axis=0)).astype(np.float32)
        return Trajectory(position, np.full(PARTICLES, sand, np.int64), key=key)

    splits = {"train": [trajectory(f"train_{i:05d}") for i in range(count)], "valid": [trajectory("valid_0")]}
    metadata = DatasetMetadata(
        bounds=[(0.0, 1.0), (0.0, 1.0)],
        sequence_length=FRAMES,
        default_connectivity_radius=2.1 * SPACING,
        dim=2,
        dt=0.005,
        **compute_statistics(splits["train"][:8], registry.kinematic_types()),
    )
    registry.get("dataset", "safe").write(path, metadata, splits)
    return count


def worker(recipe_file: Path, out: Path, steps: int) -> None:
    """One torchrun rank: train ``steps`` steps, then write this rank's peak RSS."""
    from gns_framework.config.recipe import validate_recipe
    from gns_framework.plugins import load_registry
    from gns_framework.training import distributed
    from gns_framework.training.distributed import processes_from_environment
    from gns_framework.training.trainer import Trainer

    processes = processes_from_environment()
    registry = load_registry()
    recipe = validate_recipe(yaml.safe_load(recipe_file.read_text()), registry)
    started = time.perf_counter()
    trainer = Trainer(recipe, registry, run_dir=out / "run", processes=processes, progress=False)
    ready = time.perf_counter()
    try:
        trainer.train(steps)
        # An epoch's windows come from every trajectory: read each once, as a long run would have.
        for _ in trainer.data.train:
            pass
        trainer.close()
    finally:
        distributed.stop()
    figures = {
        "rank": processes.rank,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "start_s": ready - started,
        "train_s": time.perf_counter() - ready,
    }
    (out / f"rank{processes.rank}.json").write_text(json.dumps(figures))


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def measure(dataset: Path, scratch: Path, processes: int, memory: str, steps: int) -> list[dict]:
    folder = scratch / f"{memory}-{processes}"
    folder.mkdir()
    recipe = {
        "name": f"memory-{memory}",
        "dataset": {"path": str(dataset), "memory": memory},
        "model": {"latent_size": 16, "mlp_hidden_size": 16, "processor": {"name": "interaction_network"}},
        "training": {
            "steps": steps,
            "batch_size": 2,
            "threads": 1,
            "device": "cpu",
            "log_every": 10 * steps,
            "validate_every": 10 * steps,
            "checkpoint_every": 10 * steps,
        },
    }
    recipe_file = folder / "recipe.yaml"
    recipe_file.write_text(yaml.safe_dump(recipe))
    env = dict(os.environ, OMP_NUM_THREADS="1", GLOO_SOCKET_IFNAME="lo")
    command = [
        sys.executable,
        "-m",
        "torch.distributed.run",
        f"--nproc-per-node={processes}",
        "--master-addr=127.0.0.1",
        f"--master-port={free_port()}",
        __file__,
        "--worker",
        str(recipe_file),
        str(folder),
        str(steps),
    ]
    subprocess.run(command, check=True, env=env, stdout=subprocess.DEVNULL)
    return [json.loads((folder / f"rank{rank}.json").read_text()) for rank in range(processes)]


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--worker":
        worker(Path(sys.argv[2]), Path(sys.argv[3]), int(sys.argv[4]))
        return
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--megabytes", type=float, default=1500, help="positions in the train split (MB)")
    parser.add_argument("--processes", type=int, nargs="+", default=[1, 2, 4])
    parser.add_argument("--steps", type=int, default=20, help="training steps per run")
    parser.add_argument("--json", action="store_true", help="last line: the figures as one JSON object")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        scratch = Path(scratch)
        dataset = scratch / "data"
        count = write_dataset(dataset, args.megabytes)
        size = sum(f.stat().st_size for f in dataset.iterdir()) / 1e6
        print(f"dataset: {count} trajectories of {PARTICLES} particles x {FRAMES} frames, {size:.0f} MB on disk")
        print(f"{'processes':>9} {'memory':>8} {'peak RSS per rank (MB)':>30} {'start s':>8} {'train s':>8}")
        results = []
        for processes in args.processes:
            for memory in ("all", "windows"):
                ranks = measure(dataset, scratch, processes, memory, args.steps)
                peaks = [r["peak_rss_mb"] for r in ranks]
                start = max(r["start_s"] for r in ranks)
                train = max(r["train_s"] for r in ranks)
                print(f"{processes:>9} {memory:>8} {' '.join(f'{p:.0f}' for p in peaks):>30} {start:8.1f} {train:8.1f}")
                results.append({"processes": processes, "memory": memory, "peak_rss_mb": peaks, "start_s": start})
        if args.json:
            print(json.dumps({"dataset_mb": size, "trajectories": count, "runs": results}))


if __name__ == "__main__":
    main()
