"""``gns track-sync RUN``: send what an MLflow outage kept back, from ``<run>/metrics.jsonl``, once the server is
back."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", type=Path, help="run folder written by gns train with MLflow tracking")
    parser.add_argument(
        "--tracking-uri",
        help="the MLflow store to send to (default: $MLFLOW_TRACKING_URI, else sqlite:///mlflow.db in the working "
        "directory); a run folder whose record names another store is refused: the store comes from you, never "
        "from the run folder",
    )


def run(args: argparse.Namespace) -> int:
    from ..training.mlflow_tracker import sync_run

    run_id, sent, status = sync_run(args.run, args.tracking_uri)
    ended = f"; marked {status}" if status else ""
    print(f"sent {sent} metric value(s) of {args.run} to MLflow run {run_id}{ended}")
    return 0
