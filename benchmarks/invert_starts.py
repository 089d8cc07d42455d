"""Several starts of one inversion as one batch, against the same starts one after the other.

``gns invert`` with ``optimizer.starts: M`` rolls the M starting points out as one
batch per iteration (:func:`gns_framework.inverse.solve.solve_starts`). This times one
loss-and-gradient evaluation (a whole differentiable rollout and its backward) of the M
points batched, and of each point alone, alternating the two ``--repeats`` times so
that load on a shared machine hits both alike; it also checks that the batch gives each
start the loss and gradient it has alone.

Usage::

    python benchmarks/invert_starts.py --model models/sand2d_fast.pt --data data/invert_heldout \\
        --starts 1 4 8 16 --repeats 3 --threads 1

Prints one row per M: seconds per start-evaluation alone and batched, their ratio
(above 1: the batch is faster per start), and the largest relative difference of a
loss and of a gradient between the two; the last line is the same as one JSON object.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np
import torch


def evaluate(problem, points: torch.Tensor) -> tuple[float, np.ndarray, np.ndarray]:
    """Seconds, losses (M,) and gradients (M, k) of one batched evaluation at ``points`` (M, k)."""
    u = points.clone().requires_grad_(True)
    started = time.perf_counter()
    losses, _ = problem.losses(u)
    (gradient,) = torch.autograd.grad(losses.sum(), u)
    return time.perf_counter() - started, losses.detach().double().numpy(), gradient.double().numpy()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", type=Path, default=Path("models/sand2d_fast.pt"))
    parser.add_argument("--data", type=Path, required=True, help="a dataset of the model's scene (its test split)")
    parser.add_argument("--trajectory", type=int, default=0)
    parser.add_argument("--starts", type=int, nargs="+", default=[1, 4, 8, 16])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--loss", choices=("positions", "runout", "sinkhorn"), default="positions")
    parser.add_argument("--checkpoint-every", type=int, default=10)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)

    from gns_framework.inverse.config import parse_invert_config
    from gns_framework.inverse.optimize import spread_starts
    from gns_framework.inverse.solve import prepare
    from gns_framework.plugins import load_registry
    from gns_framework.runtime.activation_memory import activations_recomputed

    raw = {
        "model": str(args.model),
        "observed": {"dataset": str(args.data), "split": "test", "trajectory": args.trajectory, "frames": "all"},
        "unknowns": {"friction": {"bounds": [0.6, 0.83]}},  # inside the model's trained range
        "loss": args.loss,
        "checkpoint_every": args.checkpoint_every,
    }
    config, unknowns = parse_invert_config(raw, "benchmark")
    problem = prepare(config, unknowns, "benchmark", load_registry()).problem
    fixed = problem.parameters.high == problem.parameters.low
    rows = []
    with activations_recomputed(args.checkpoint_every > 0):
        evaluate(problem, torch.tensor(problem.start[None]))  # warm-up: kernels compiled, caches filled
        for starts in args.starts:
            points = torch.tensor(spread_starts(problem.start, starts, 0, fixed))
            alone_times, batch_times = [], []
            for _ in range(args.repeats):
                singles = [evaluate(problem, point[None]) for point in points]
                alone_times.append(sum(seconds for seconds, _, _ in singles) / starts)
                seconds, losses, gradients = evaluate(problem, points)
                batch_times.append(seconds / starts)
            alone_losses = np.concatenate([loss for _, loss, _ in singles])
            alone_gradients = np.concatenate([gradient for _, _, gradient in singles])
            alone, batched = statistics.median(alone_times), statistics.median(batch_times)
            rows.append(
                {
                    "starts": starts,
                    "particles": int(problem.state.num_particles * starts),
                    "seconds_per_start_alone": alone,
                    "seconds_per_start_batched": batched,
                    "speedup": alone / batched,
                    "loss_difference": float(np.max(np.abs(losses - alone_losses) / np.abs(alone_losses))),
                    "gradient_difference": float(
                        np.max(np.abs(gradients - alone_gradients)) / np.max(np.abs(alone_gradients))
                    ),
                }
            )
            row = rows[-1]
            print(
                f"starts {starts:3d} ({row['particles']:6d} particles): {alone:.3f} s per start alone, "
                f"{batched:.3f} s batched, {row['speedup']:.2f}x; largest relative difference of a loss "
                f"{row['loss_difference']:.1e}, of a gradient {row['gradient_difference']:.1e}"
            )
    print(json.dumps({"model": str(args.model), "trajectory": problem.trajectory.key, "rows": rows}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
