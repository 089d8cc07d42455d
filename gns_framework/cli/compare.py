"""``gns compare``: the runs of an MLflow experiment side by side, as a table and a plot of their curves."""

from __future__ import annotations

import argparse
from pathlib import Path

DEFAULT_METRICS = ["train_loss", "valid_one_step_position_mse", "steps_per_s"]
DEFAULT_PARAMS = ["world_size", "model.latent_size", "model.processor.message_passing_steps", "training.batch_size"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("experiment", help="MLflow experiment name (gns train logs to the recipe's name by default)")
    parser.add_argument("--metrics", nargs="+", default=DEFAULT_METRICS, metavar="METRIC", help="metric columns and plot panels")
    parser.add_argument(
        "--params", nargs="+", default=DEFAULT_PARAMS, metavar="PARAM",
        help="param columns: logged names (world_size, git_commit) or recipe keys (model.latent_size)",
    )
    parser.add_argument("--sort", metavar="METRIC", help="sort by this metric, smallest first (default: the first metric)")
    parser.add_argument("--plot", type=Path, help="plot file (default: <experiment>-compare.png)")
    parser.add_argument("--tracking-uri", help="MLflow tracking URI (default: as gns train)")


def run(args: argparse.Namespace) -> int:
    from ..training.comparison import experiment_runs, format_table, plot_histories, sort_runs
    from ..training.mlflow_tracker import default_tracking_uri

    uri = args.tracking_uri or default_tracking_uri()
    runs = experiment_runs(uri, args.experiment, args.metrics, args.params)
    runs = sort_runs(runs, args.sort or args.metrics[0])
    print(format_table(runs, args.metrics, args.params))
    plot = plot_histories(runs, args.metrics, args.plot or Path(f"{args.experiment}-compare.png"), args.experiment)
    print(f"{len(runs)} runs; plot in {plot}")
    return 0
