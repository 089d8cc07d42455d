"""Training throughput of `gns train` on 1 and 2 processes (torchrun, DDP): steps/s and particles/s.

Trains the reference GNS architecture (or a smaller one, see --help) on a synthetic
soft-sphere dataset for a few dozen steps per configuration and reads the throughput
that the trainer logs (optimiser steps only: no validation or checkpoint time). Each
process trains on --batch-size windows, so a step of N processes covers N times the
windows of a step of one: compare particles/s for scaling.

    python benchmarks/ddp_throughput.py                 # CPU, 1 and 2 processes; GPUs too when present
    python benchmarks/ddp_throughput.py --latent 64 --message-passing-steps 5 --steps 40
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import torch
import yaml

ROOT = Path(__file__).resolve().parents[1]
# The soft-sphere scene generator lives with the tests.
sys.path.insert(0, str(ROOT / "tests"))

from synthetic import write_synthetic_dataset  # noqa: E402


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def write_recipe(folder: Path, dataset: Path, args: argparse.Namespace, device: str) -> Path:
    recipe = {
        "name": "throughput",
        "dataset": {"path": str(dataset)},
        "model": {
            "latent_size": args.latent,
            "mlp_hidden_size": args.latent,
            "processor": {"name": "interaction_network", "message_passing_steps": args.message_passing_steps},
        },
        "training": {
            "steps": args.steps,
            "batch_size": args.batch_size,
            "log_every": args.log_every,
            "validate_every": 10 * args.steps,
            "checkpoint_every": 10 * args.steps,
            "device": device,
        },
    }
    path = folder / f"recipe-{device}.yaml"
    path.write_text(yaml.safe_dump(recipe))
    return path


def measure(recipe: Path, processes: int, threads: int, run_dir: Path) -> tuple[float, float]:
    """Median steps/s and particles/s over the logged windows after the first (warm-up)."""
    command = [
        sys.executable,
        "-m",
        "torch.distributed.run",
        "--nnodes",
        "1",
        "--nproc-per-node",
        str(processes),
        "--master-addr",
        "127.0.0.1",
        "--master-port",
        str(free_port()),
        "--local-addr",
        "127.0.0.1",
        "-m",
        "gns_framework.cli",
        "train",
        str(recipe),
        "--out",
        str(run_dir),
        "--no-tracking",
        "--no-progress",
    ]
    env = dict(os.environ, OMP_NUM_THREADS=str(threads), PYTHONPATH=str(ROOT))
    subprocess.run(command, env=env, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    logged = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()][1:]
    return statistics.median(m["steps_per_s"] for m in logged), statistics.median(m["particles_per_s"] for m in logged)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--processes", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--steps", type=int, default=60)
    parser.add_argument("--log-every", type=int, default=10)
    parser.add_argument("--batch-size", type=int, default=2, help="windows per process and step")
    parser.add_argument("--latent", type=int, default=128)
    parser.add_argument("--message-passing-steps", type=int, default=10)
    parser.add_argument("--block", type=int, default=8, help="particles per scene: block**2 (2D)")
    parser.add_argument("--threads", type=int, help="torch threads per process (default: CPU cores / processes)")
    args = parser.parse_args()

    cores = os.cpu_count() or 1
    gpus = torch.cuda.device_count() if torch.cuda.is_available() else 0
    rows = []
    with tempfile.TemporaryDirectory(prefix="gns-throughput-") as tmp:
        folder = Path(tmp)
        dataset = write_synthetic_dataset(folder / "data", train=4, valid=1, test=0, block=args.block)
        devices = [("cpu", n) for n in args.processes] + [("cuda", n) for n in args.processes if n <= gpus]
        for device, processes in devices:
            threads = args.threads or max(1, cores // processes)
            recipe = write_recipe(folder, dataset, args, device)
            steps, particles = measure(recipe, processes, threads, folder / f"run-{device}-{processes}")
            rows.append((device, processes, threads, steps, particles))

    print(
        f"gns train throughput: latent {args.latent}, {args.message_passing_steps} message-passing steps, "
        f"{args.block**2} particles per window, {args.batch_size} windows per process; "
        f"{cores} CPU cores, {gpus} GPUs{'' if gpus else ' (no GPU available: CPU rows only)'}"
    )
    print(f"{'device':<7}{'processes':>10}{'threads':>9}{'steps/s':>10}{'particles/s':>13}{'scaling':>9}")
    base = {}
    for device, processes, threads, steps, particles in rows:
        base.setdefault(device, particles)
        print(
            f"{device:<7}{processes:>10}{threads:>9}{steps:>10.2f}{particles:>13.0f}{particles / base[device]:>8.2f}x"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
