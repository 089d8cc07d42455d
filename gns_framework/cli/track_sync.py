"""``gns track-sync RUN``: send what an MLflow outage kept back, from ``<run>/metrics.jsonl``, once the server is back."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", type=Path, help="run folder written by gns train with MLflow tracking")


def run(args: argparse.Namespace) -> int:
    from ..training.mlflow_tracker import sync_run

    run_id, sent, status = sync_run(args.run)
    ended = f"; marked {status}" if status else ""
    print(f"sent {sent} metric value(s) of {args.run} to MLflow run {run_id}{ended}")
    return 0
