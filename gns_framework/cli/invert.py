"""``gns invert``: recover material properties or initial velocities by differentiating the learned rollout.

The configuration file is described in :mod:`gns_framework.inverse.config` and in
docs/inverse.md. Results go to a new folder: one that already holds an inversion's
results is refused, so nothing written before is replaced.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..errors import GnsError
from ..safe_names import safe_component
from .arguments import add_allow_pickle
from .envelope_option import add_outside_envelope
from .tracking_options import add_tracking_arguments, check_tracking_arguments, with_mlflow

OUTPUTS = ("result.json", "metrics.jsonl", "convergence.png", "rollout.npz", "rollout.gif")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("config", type=Path, help="inversion config YAML (model, observed, unknowns, optimizer, loss)")
    parser.add_argument("--out", type=Path, help="results folder (default: runs/invert/<config file name>)")
    add_allow_pickle(parser)
    parser.add_argument("--no-gif", action="store_true", help="do not animate the recovered rollout")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_outside_envelope(parser)
    add_tracking_arguments(parser, "<out>/metrics.jsonl", "invert")


def run(args: argparse.Namespace) -> int:
    import torch
    from tqdm import tqdm

    from ..inverse.config import load_invert_config
    from ..inverse.solve import iteration_metrics, prepare, solve, write_outputs
    from ..plugins import load_registry
    from ..training.tracking import JsonlTracker

    check_tracking_arguments(args)
    config, unknowns = load_invert_config(args.config)
    out = args.out or Path("runs/invert") / safe_component(args.config.stem)
    earlier = [name for name in OUTPUTS if (out / name).exists()]
    if earlier:
        raise GnsError(
            f"{out}: holds an earlier inversion ({', '.join(earlier)}); choose another --out or move it away"
        )
    if config.threads:
        torch.set_num_threads(config.threads)
    inversion = prepare(config, unknowns, args.config, load_registry(), args.allow_pickle, args.outside_envelope)
    for line in inversion.warnings:
        print(f"gns invert: warning: {line}", file=sys.stderr)
    tracker = with_mlflow(args, "invert", out, JsonlTracker(out), resume=False, activity="the inversion")
    tracker.log_params(
        {
            "config": config.model_dump(mode="json"),
            "config_file": str(args.config),
            **({"outside_envelope": "; ".join(inversion.warnings)} if inversion.warnings else {}),
        }
    )
    bar = tqdm(total=config.optimizer.iterations, desc="invert", unit="it", disable=args.no_progress)

    def on_iteration(iterate) -> None:
        metrics = iteration_metrics(inversion, iterate)
        tracker.log_metrics(metrics, iterate.iteration)
        bar.set_postfix_str(", ".join(f"{name} {value:.4g}" for name, value in metrics.items()))
        # One tick per iteration, whichever start reports it first; the final points come after the last.
        if bar.n < iterate.iteration <= config.optimizer.iterations:
            bar.update(iterate.iteration - bar.n)

    try:
        result = solve(inversion, on_iteration)
    except BaseException:
        bar.close()
        tracker.close(failed=True)
        raise
    bar.close()
    paths = write_outputs(inversion, result, out, gif=not args.no_gif)
    for path in paths.values():
        tracker.log_artifact(path)
    assert result.best is not None  # solve sets it
    tracker.log_metrics(
        {"final_loss": result.loss, "best_iteration": result.best.iteration, "seconds": result.seconds},
        result.iterations,
    )
    tracker.close()
    recovered = ", ".join(f"{k} {v}" for k, v in result.unknowns.items())
    chosen = "held-out loss" if result.selected_by == "held_out" else "loss"
    starts = config.optimizer.starts
    where = f", start {result.best.start} of {starts}" if starts > 1 else ""
    rollouts = (
        f"{result.evaluations} batched rollouts of {starts} starts" if starts > 1 else f"{result.evaluations} rollouts"
    )
    print(
        f"recovered {recovered} (best {chosen}: iteration {result.best.iteration}{where}); loss ({config.loss}) "
        f"{result.loss:.4g} after {result.iterations} iterations, {rollouts}, {result.seconds:.1f} s"
    )
    errors = result.errors(inversion.truth)
    if errors:
        assert inversion.truth is not None  # the errors are against it
        print("true " + ", ".join(f"{name} {inversion.truth[name]} (error {errors[name]:.2f} %)" for name in errors))
    for kind, path in paths.items():
        print(f"{kind}: {path}")
    sys.stdout.flush()
    return 0
