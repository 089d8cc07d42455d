"""``gns compare``: tracked runs of any experiments side by side, as a table and a plot of their curves.

The table shows the chosen params and every recipe field that differs between the runs.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..safe_names import safe_component

DEFAULT_METRICS = [
    "train_loss",
    "valid_one_step_position_mse",
    "valid_rollout_mse",
    "valid_rollout_sinkhorn_pct",
    "valid_rollout_deposit_error_pct",
    "steps_per_s",
]
"""Shown when --metrics is not given: loss, one-step and rollout validation (what recipes are compared on), pace;
those the runs did not log are left out without a word."""
DEFAULT_PLOT = Path("-")
"""--plot given without a file: the plot's default name."""
DEFAULT_PARAMS = ["world_size"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "runs",
        nargs="*",
        metavar="EXPERIMENT_OR_RUN",
        help="MLflow experiment names (gns train logs to the recipe's name by default) and run ids "
        "(or their first 8+ hex digits, as the table prints them), in any mix",
    )
    parser.add_argument(
        "--filter",
        metavar="FILTER",
        help="MLflow search filter the runs must match, e.g. \"params.recipe.model.latent_size = '32'\" or "
        "\"tags.team = 'geo'\"; alone, it searches every experiment",
    )
    parser.add_argument(
        "--metrics",
        nargs="+",
        metavar="METRIC",
        help=f"metric columns and plot panels (default: those of {', '.join(DEFAULT_METRICS)} the runs logged)",
    )
    parser.add_argument(
        "--params",
        nargs="+",
        default=DEFAULT_PARAMS,
        metavar="PARAM",
        help="param columns besides the recipe fields that differ between the runs: logged names "
        "(world_size, git_commit) or recipe keys (model.latent_size)",
    )
    parser.add_argument(
        "--sort", metavar="METRIC", help="sort by this metric, smallest first (default: the first metric)"
    )
    parser.add_argument(
        "--plot",
        type=Path,
        nargs="?",
        const=DEFAULT_PLOT,
        metavar="FILE",
        help="also plot the curves into FILE; --plot alone: compare-<experiments>-<metrics>.png in the working "
        "directory (names joined by dots). Without --plot no file is written",
    )
    parser.add_argument("--tracking-uri", help="MLflow tracking URI (default: as gns train)")


def run(args: argparse.Namespace) -> int:
    from ..errors import GnsError
    from ..training.comparison import (
        differing_recipe_fields,
        format_table,
        logged_metrics,
        plot_histories,
        select_runs,
        sort_runs,
        unlogged,
    )
    from ..training.mlflow_tracker import default_tracking_uri

    uri = args.tracking_uri or default_tracking_uri()
    asked = args.metrics or DEFAULT_METRICS
    runs = select_runs(uri, args.runs, asked, args.filter)
    if not runs:
        raise GnsError(f"no runs match {' '.join(args.runs)} {args.filter or ''}".rstrip())
    missing = unlogged(runs, asked)
    for metric in missing if args.metrics else ():  # a default the runs did not log is no news
        print(
            f"gns compare: warning: no run logged metric {metric!r}; logged metrics: {', '.join(logged_metrics(runs))}",
            file=sys.stderr,
        )
    metrics = [metric for metric in asked if metric not in missing]
    if not metrics:
        raise GnsError(f"none of the metrics {', '.join(asked)} was logged by these runs")
    sort = args.sort or metrics[0]
    if sort in unlogged(runs, [sort]):
        raise GnsError(f"--sort {sort}: no run logged it; logged metrics: {', '.join(logged_metrics(runs))}")
    params = args.params + [key for key in differing_recipe_fields(runs) if key not in args.params]
    print(format_table(sort_runs(runs, sort), metrics, params))
    title = " ".join(args.runs) or args.filter
    experiments = sorted({run.experiment for run in runs})
    summary = f"{len(runs)} runs of {len(experiments)} experiment(s) ({', '.join(experiments)})"
    if args.plot is None:
        print(summary)
        return 0
    path = default_plot_name(experiments, metrics) if args.plot == DEFAULT_PLOT else args.plot
    plot = plot_histories(runs, metrics, path, title)
    print(f"{summary}; plot in {plot}")
    return 0


def default_plot_name(experiments: list[str], metrics: list[str]) -> Path:
    """``compare-<experiments>-<metrics>.png``: what the plot compares, by experiment name even when runs were
    given by id, as one safe file name in the working directory (names from the store are never paths)."""
    stem = f"compare-{'.'.join(experiments)}-{'.'.join(metrics)}"
    if len(stem) > 120:  # many experiments or metrics: the name stays a name, the table says the rest
        stem = (
            f"compare-{experiments[0]}{'.more' if len(experiments) > 1 else ''}"
            f"-{metrics[0]}{'.more' if len(metrics) > 1 else ''}"
        )
    return Path(f"{safe_component(stem[:200])}.png")
