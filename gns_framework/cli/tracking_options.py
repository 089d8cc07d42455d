"""MLflow tracking options shared by the commands that track a run (``gns train``, ``gns invert``)."""

from __future__ import annotations

import argparse
import os
import warnings
from pathlib import Path

from ..training.tracking import Tracker, TrackerGroup


def add_tracking_arguments(parser: argparse.ArgumentParser, metrics_file: str, default_experiment: str) -> None:
    """``--tracking-uri``, ``--experiment`` and ``--no-tracking``; ``metrics_file`` is where metrics always go."""
    tracking = parser.add_argument_group(
        "tracking (MLflow; rank 0 only)",
        f"Metrics always go to {metrics_file}. The command never waits on the tracking server: what it misses "
        "while unreachable is sent when it is back (tried every $GNS_TRACKING_RETRY_SECONDS, default 30); an ending "
        "run waits at most $GNS_TRACKING_CLOSE_SECONDS (default 60), then warns what the server did not receive. "
        "A server unreachable at the start leaves the run untracked, with a warning.",
    )
    tracking.add_argument(
        "--tracking-uri",
        help="MLflow tracking URI, e.g. http://host:5000 (default: $MLFLOW_TRACKING_URI, else sqlite:///mlflow.db "
        "in the working directory, created on first use)",
    )
    tracking.add_argument("--experiment", help=f"MLflow experiment name (default: {default_experiment})")
    tracking.add_argument("--no-tracking", action="store_true", help=f"no MLflow; metrics go to {metrics_file} only")


def check_tracking_arguments(args: argparse.Namespace) -> None:
    """Refuse a malformed tracking URI (--tracking-uri or $MLFLOW_TRACKING_URI) before anything is written."""
    from ..training import mlflow_tracker

    if args.no_tracking:
        return
    if args.tracking_uri:
        mlflow_tracker.validate_tracking_uri(args.tracking_uri, "--tracking-uri")
    elif os.environ.get("MLFLOW_TRACKING_URI"):
        mlflow_tracker.validate_tracking_uri(os.environ["MLFLOW_TRACKING_URI"], "$MLFLOW_TRACKING_URI")


def with_mlflow(
    args: argparse.Namespace, experiment: str, run_dir: Path, local: Tracker, resume: bool, activity: str = "training"
) -> Tracker:
    """``local`` (the run folder's metrics file) plus an MLflow run, unless tracking is off or mlflow is missing.

    ``experiment`` is the default name, used when ``--experiment`` is not given; ``activity``
    names what goes on without a server in the warning.
    """
    from ..training import mlflow_tracker

    if args.no_tracking:
        return local
    if args.tracking_uri is None and not mlflow_tracker.mlflow_available():
        print("mlflow is not installed: metrics go to the run folder only (pip install 'gns-framework[tracking]')")
        return local
    uri = args.tracking_uri or mlflow_tracker.default_tracking_uri()
    try:
        mlflow = mlflow_tracker.open_mlflow_tracker(run_dir, uri, args.experiment or experiment, resume)
    except mlflow_tracker.TrackingError:
        raise
    except Exception as error:
        if not mlflow_tracker.server_unreachable(error):
            raise mlflow_tracker.TrackingError(f"MLflow at {uri}: {mlflow_tracker.first_line(error)}") from None
        # The command never waits on tracking: without a server at the start, this run is not in MLflow.
        warnings.warn(
            f"tracking: MLflow at {uri} unreachable ({mlflow_tracker.first_line(error)}); {activity} goes on "
            f"without it, the metrics go to {run_dir / 'metrics.jsonl'} only",
            stacklevel=2,
        )
        return local
    print(f"tracking run {mlflow.run_id} in {uri}")
    return TrackerGroup([local, mlflow])
