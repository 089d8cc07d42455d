"""An MLflow run as a Tracker (rank 0 only).

mlflow is imported when a tracker is opened, never when this module is imported,
so ``import gns_framework`` and ``gns --help`` stay light and mlflow stays an
optional extra (``pip install 'gns-framework[tracking]'``).

The run's id is kept in ``<run_dir>/mlflow_run.json``; a resumed training (``--resume``
or an elastic restart) goes on logging into the same MLflow run.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..data.atomic import write_text_atomic
from ..errors import GnsError

RUN_FILE = "mlflow_run.json"
DEFAULT_DATABASE = "mlflow.db"
ARTIFACTS_FOLDER = "mlartifacts"
_PARAMS_PER_REQUEST = 100


class TrackingError(GnsError):
    """The tracking backend is missing or refused the run."""


def default_tracking_uri() -> str:
    """``MLFLOW_TRACKING_URI`` when set, else a SQLite database in the working directory (created on first use)."""
    return os.environ.get("MLFLOW_TRACKING_URI") or f"sqlite:///{Path.cwd() / DEFAULT_DATABASE}"


def mlflow_available() -> bool:
    try:
        import mlflow  # noqa: F401
    except ImportError:
        return False
    return True


def _client(tracking_uri: str):
    try:
        from mlflow.tracking import MlflowClient
    except ImportError:
        raise TrackingError(
            "MLflow tracking needs mlflow: pip install 'gns-framework[tracking]' (or train with --no-tracking)"
        ) from None
    return MlflowClient(tracking_uri)


def local_database(tracking_uri: str) -> Path | None:
    """The file of a ``sqlite:///`` tracking URI; None for other stores."""
    prefix = "sqlite:///"
    return Path(tracking_uri[len(prefix) :]) if tracking_uri.startswith(prefix) else None


def _local_artifact_root(tracking_uri: str, experiment: str) -> str | None:
    """Artifacts of a local SQLite store go beside the database, wherever the UI is started from."""
    database = local_database(tracking_uri)
    if database is None:
        return None
    return (database.parent / ARTIFACTS_FOLDER / experiment).resolve().as_uri()


def experiment_id(client, tracking_uri: str, name: str, create: bool = True) -> str | None:
    """The id of experiment ``name``; created when missing and ``create``."""
    found = client.get_experiment_by_name(name)
    if found is not None:
        return found.experiment_id
    if not create:
        return None
    return client.create_experiment(name, artifact_location=_local_artifact_root(tracking_uri, name))


def flatten(params: dict[str, Any], prefix: str = "") -> dict[str, str]:
    """Nested mapping -> ``{"a.b.c": "value"}`` with MLflow-safe string values (lists as JSON)."""
    flat: dict[str, str] = {}
    for key, value in params.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict) and value:
            flat.update(flatten(value, f"{name}."))
        elif isinstance(value, (list, tuple, dict)):
            flat[name] = json.dumps(value)
        else:
            flat[name] = str(value)
    return flat


class MlflowTracker:
    """Logs params, metrics and artifacts of one training run to an MLflow tracking store.

    Args:
        tracking_uri: ``sqlite:///path.db``, ``http://host:port`` of an ``mlflow server``, ...
        experiment: experiment name (created when missing).
        run_name: shown in the MLflow UI.
        run_id: continue this existing run instead of starting one.
    """

    def __init__(self, tracking_uri: str, experiment: str, run_name: str | None = None, run_id: str | None = None):
        self.client = _client(tracking_uri)
        from mlflow.entities import Metric, Param, RunTag

        self._metric, self._param, self._tag = Metric, Param, RunTag
        self.tracking_uri = tracking_uri
        self.experiment_id = experiment_id(self.client, tracking_uri, experiment)
        if run_id is not None:
            self.run_id = run_id
            self.client.update_run(run_id, status="RUNNING")
        else:
            self.run_id = self.client.create_run(self.experiment_id, run_name=run_name).info.run_id

    def log_params(self, params: dict) -> None:
        """Log ``params`` flattened.

        MLflow params cannot change, so a resumed run keeps the values it started
        with and records each changed one (more ``training.steps``, say) as a tag
        ``changed.<param>`` = ``"old -> new"``.
        """
        logged = self.client.get_run(self.run_id).data.params
        flat = flatten(params)
        entries = [self._param(k, v) for k, v in flat.items() if k not in logged]
        changes = [self._tag(f"changed.{k}", f"{logged[k]} -> {v}") for k, v in flat.items() if logged.get(k, v) != v]
        for i in range(0, len(entries), _PARAMS_PER_REQUEST):
            self.client.log_batch(self.run_id, params=entries[i : i + _PARAMS_PER_REQUEST])
        for i in range(0, len(changes), _PARAMS_PER_REQUEST):
            self.client.log_batch(self.run_id, tags=changes[i : i + _PARAMS_PER_REQUEST])

    def log_metrics(self, metrics: dict[str, float], step: int) -> None:
        now = int(time.time() * 1000)
        entries = [self._metric(k, float(v), now, step) for k, v in metrics.items() if math.isfinite(v)]
        if entries:
            self.client.log_batch(self.run_id, metrics=entries)

    def log_artifact(self, path: Path) -> None:
        self.client.log_artifact(self.run_id, str(path))

    def close(self, failed: bool = False) -> None:
        self.client.set_terminated(self.run_id, status="FAILED" if failed else "FINISHED")


def open_mlflow_tracker(run_dir: Path, tracking_uri: str, experiment: str, resume: bool) -> MlflowTracker:
    """The MLflow run of ``run_dir``: the one it logged to before when resuming there, else a new one."""
    record = Path(run_dir) / RUN_FILE
    if resume and record.is_file():
        saved = json.loads(record.read_text())
        if saved.get("tracking_uri") == tracking_uri and saved.get("experiment") == experiment:
            return MlflowTracker(tracking_uri, experiment, run_id=saved["run_id"])
    tracker = MlflowTracker(tracking_uri, experiment, run_name=Path(run_dir).name)
    record.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(
        record, json.dumps({"tracking_uri": tracking_uri, "experiment": experiment, "run_id": tracker.run_id}) + "\n"
    )
    return tracker


def log_to_recorded_run(
    run_dir: Path, metrics: dict[str, float], step: int, artifacts: Sequence[Path] = (), artifact_path: str | None = None
) -> str | None:
    """Add ``metrics`` (and ``artifacts`` under ``artifact_path``) to the MLflow run that trained ``run_dir``.

    The run's status is left alone. Returns the run id, or None when the run was not
    tracked with MLflow (or mlflow is missing).
    """
    record = Path(run_dir) / RUN_FILE
    if not record.is_file() or not mlflow_available():
        return None
    saved = json.loads(record.read_text())
    from mlflow.entities import Metric

    now = int(time.time() * 1000)
    entries = [Metric(k, float(v), now, step) for k, v in metrics.items() if math.isfinite(v)]
    client = _client(saved["tracking_uri"])
    client.log_batch(saved["run_id"], metrics=entries)
    for artifact in artifacts:
        client.log_artifact(saved["run_id"], str(artifact), artifact_path)
    return saved["run_id"]
