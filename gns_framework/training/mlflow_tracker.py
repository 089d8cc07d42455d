"""An MLflow run as a Tracker (rank 0 only).

mlflow is imported when a tracker is opened, never when this module is imported,
so ``import gns_framework`` and ``gns --help`` stay light and mlflow stays an
optional extra (``pip install 'gns-framework[tracking]'``).

The run's id is kept in ``<run_dir>/mlflow_run.json``; a resumed training (``--resume``
or an elastic restart) goes on logging into the same MLflow run.

A tracking server that is slow or down never holds up or ends training: the run's
params, metrics and artifacts go out from a thread of their own (Outbox), in order,
and what an outage kept back goes out when the server is back. The metrics are in
the run folder's ``metrics.jsonl`` whatever happens to the server.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import time
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..data.atomic import write_text_atomic
from ..errors import GnsError
from ..io.run_folder import RunFolder
from ..safe_names import ensure_inside, safe_component
from .mlflow_outbox import METRICS_PER_REQUEST, Outbox, Request, first_line, server_unreachable

DEFAULT_DATABASE = "mlflow.db"
ARTIFACTS_FOLDER = "mlartifacts"
_PARAMS_PER_REQUEST = 100
"""MLflow's limit of params in one log_batch request (metrics: METRICS_PER_REQUEST)."""

REQUEST_LIMITS = {"MLFLOW_HTTP_REQUEST_TIMEOUT": "10", "MLFLOW_HTTP_REQUEST_MAX_RETRIES": "2"}
"""Defaults for MLflow's HTTP client where the environment sets none. MLflow's own
(120 s a request, 7 retries with growing pauses) wait about 4 minutes on a server
that is down, which a training start or a run's final flush should not."""

RETRY_SECONDS = "GNS_TRACKING_RETRY_SECONDS"
"""Environment variable: seconds between tries while the tracking server is unreachable (default 30)."""
CLOSE_SECONDS = "GNS_TRACKING_CLOSE_SECONDS"
"""Environment variable: the longest an ending run waits to send what an outage kept back (default 60)."""


class TrackingError(GnsError):
    """The tracking backend is missing or refused the run."""


def default_tracking_uri() -> str:
    """``MLFLOW_TRACKING_URI`` when set, else a SQLite database in the working directory (created on first use)."""
    return os.environ.get("MLFLOW_TRACKING_URI") or f"sqlite:///{Path.cwd() / DEFAULT_DATABASE}"


TRACKING_SCHEMES = ("http", "https", "sqlite", "postgresql", "mysql", "mssql", "file")
"""The tracking stores MLflow's client opens: a server (http, https), a database, or a local folder."""
_MLFLOW_TABLES = {"experiments", "runs"}
"""Tables every MLflow SQL store has: an SQLite file with other tables and not these belongs to something else."""


def validate_tracking_uri(uri: str, source: str = "tracking URI") -> str:
    """``uri`` when it is a tracking store MLflow can open, else a TrackingError naming ``source`` and the form.

    Checked before any store is touched: a malformed URI never reaches MLflow (whose
    errors are tracebacks), and an SQLite file that exists must be an MLflow store,
    so MLflow never creates its tables inside an unrelated database.
    """
    from urllib.parse import urlsplit

    forms = "http(s)://host[:port], sqlite:///path/to/mlflow.db, postgresql://..., mysql://..., file:///folder"
    if not isinstance(uri, str) or not uri.strip() or any(c in uri for c in "\r\n\x00"):
        raise TrackingError(f"{source} {uri!r}: not a URI; expected {forms}")
    try:
        parts = urlsplit(uri)
        _ = parts.port  # parsed on access: a bad port or bracket raises ValueError
    except ValueError as exc:
        raise TrackingError(f"{source} {uri!r}: malformed ({exc}); expected {forms}") from None
    scheme = parts.scheme.split("+")[0].lower()
    if scheme not in TRACKING_SCHEMES:
        raise TrackingError(f"{source} {uri!r}: unsupported scheme {parts.scheme or '(none)'!r}; expected {forms}")
    if scheme in ("http", "https") and not parts.hostname:
        raise TrackingError(f"{source} {uri!r}: no host; expected {scheme}://host[:port]")
    database = local_database(uri)
    if scheme == "sqlite" and database is None:
        raise TrackingError(f"{source} {uri!r}: expected sqlite:///path/to/mlflow.db (three slashes, then the path)")
    if database is not None and database.exists():
        _check_mlflow_database(database, source, uri)
    return uri


def _check_mlflow_database(database: Path, source: str, uri: str) -> None:
    """Refuse an existing SQLite file that is not an MLflow store (or not a database at all)."""
    import sqlite3

    if not database.is_file():
        raise TrackingError(f"{source} {uri!r}: {database} is not a file")
    if database.stat().st_size == 0:
        return  # an empty file: MLflow makes a new store in it
    try:
        with contextlib.closing(sqlite3.connect(f"{database.resolve().as_uri()}?mode=ro", uri=True)) as connection:
            tables = {row[0] for row in connection.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
    except sqlite3.Error as exc:
        raise TrackingError(f"{source} {uri!r}: {database} is not an SQLite database ({exc})") from None
    if tables and not tables >= _MLFLOW_TABLES:
        shown = ", ".join(sorted(tables)[:5]) + (" ..." if len(tables) > 5 else "")
        raise TrackingError(
            f"{source} {uri!r}: {database} is a database of something else (tables {shown}), not an MLflow store; "
            "MLflow would add its tables to it"
        )


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
    for name, value in REQUEST_LIMITS.items():
        os.environ.setdefault(name, value)
    try:
        return MlflowClient(tracking_uri)
    except Exception as error:  # MLflow's refusals of a store (a file store it no longer opens, say) are long
        raise TrackingError(f"MLflow cannot open the store {tracking_uri}: {first_line(error)}") from None


def _seconds(variable: str, default: float) -> float:
    text = os.environ.get(variable)
    if text is None:
        return default
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not value >= 0:
        raise TrackingError(f"{variable}={text!r}: must be a number of seconds, 0 or more")
    return value


def local_database(tracking_uri: str) -> Path | None:
    """The file of a ``sqlite:///`` tracking URI; None for other stores."""
    prefix = "sqlite:///"
    return Path(tracking_uri[len(prefix) :]) if tracking_uri.startswith(prefix) else None


def _local_artifact_root(tracking_uri: str, experiment: str) -> str | None:
    """Artifacts of a local SQLite store go beside the database, wherever the UI is started from.

    The experiment's folder is its name made a safe folder name, checked to be inside
    ``mlartifacts/`` (``--experiment ../../x`` writes nothing outside the store).
    """
    database = local_database(tracking_uri)
    if database is None:
        return None
    root = database.parent / ARTIFACTS_FOLDER
    return ensure_inside(root / safe_component(experiment), root).resolve().as_uri()


EXPERIMENT_KIND = ("mlflow.experimentKind", "custom_model_development")
"""The experiment tag that makes MLflow 3's UI open a training experiment on its runs, metrics
and charts; without it, the UI may open on its GenAI view, where these runs hide under
"Evaluation runs"."""


def experiment_id(client, tracking_uri: str, name: str, create: bool = True) -> str | None:
    """The id of experiment ``name``; created when missing and ``create``, marked as model training.

    An experiment this framework made before the mark existed gets it now; one that a
    user typed differently (any other kind) keeps theirs.
    """
    found = client.get_experiment_by_name(name)
    if found is not None:
        if create and EXPERIMENT_KIND[0] not in found.tags:
            client.set_experiment_tag(found.experiment_id, *EXPERIMENT_KIND)
        return found.experiment_id
    if not create:
        return None
    return client.create_experiment(
        name, artifact_location=_local_artifact_root(tracking_uri, name), tags=dict([EXPERIMENT_KIND])
    )


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

    Opening the run (and continuing one) talks to the server at once, within
    REQUEST_LIMITS; everything after goes through an Outbox, so a server that goes
    away during training costs the training nothing.

    Args:
        tracking_uri: ``sqlite:///path.db``, ``http://host:port`` of an ``mlflow server``, ...
        experiment: experiment name (created when missing).
        run_name: shown in the MLflow UI.
        run_id: continue this existing run instead of starting one.
        kept_in: where the metrics are kept locally, for the warnings of an outage.
    """

    def __init__(
        self,
        tracking_uri: str,
        experiment: str,
        run_name: str | None = None,
        run_id: str | None = None,
        kept_in: str = "the run folder's metrics.jsonl",
        run_dir: Path | None = None,
    ):
        self.run_dir = Path(run_dir) if run_dir is not None else None
        retry_seconds, close_seconds = _seconds(RETRY_SECONDS, 30.0), _seconds(CLOSE_SECONDS, 60.0)
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
        self.outbox = Outbox(
            f"MLflow at {tracking_uri}",
            kept_in,
            self._send_metrics,
            retry_seconds=retry_seconds,
            close_seconds=close_seconds,
        )

    def log_params(self, params: dict) -> None:
        """Log ``params`` flattened.

        MLflow params cannot change, so a resumed run keeps the values it started
        with and records each changed one (more ``training.steps``, say) as a tag
        ``changed.<param>`` = ``"old -> new"``.
        """
        self.outbox.put(Request("the run's params", send=lambda: self._send_params(params)))

    def _send_params(self, params: dict) -> None:
        logged = self.client.get_run(self.run_id).data.params
        flat = flatten(params)
        entries = [self._param(k, v) for k, v in flat.items() if k not in logged]
        changes = [self._tag(f"changed.{k}", f"{logged[k]} -> {v}") for k, v in flat.items() if logged.get(k, v) != v]
        for i in range(0, len(entries), _PARAMS_PER_REQUEST):
            self.client.log_batch(self.run_id, params=entries[i : i + _PARAMS_PER_REQUEST])
        for i in range(0, len(changes), _PARAMS_PER_REQUEST):
            self.client.log_batch(self.run_id, tags=changes[i : i + _PARAMS_PER_REQUEST])

    def log_metrics(self, metrics: dict[str, float], step: int) -> None:
        """Queue ``metrics`` stamped with the time of the call, not of their sending."""
        now = int(time.time() * 1000)
        entries = [self._metric(k, float(v), now, step) for k, v in metrics.items() if math.isfinite(v)]
        if entries:
            self.outbox.put(Request(f"the metrics of step {step}", metrics=entries, step=step))

    def _send_metrics(self, entries: list) -> None:
        self.client.log_batch(self.run_id, metrics=entries)

    def log_artifact(self, path: Path) -> None:
        self.outbox.put(
            Request(f"artifact {Path(path).name}", send=lambda: self.client.log_artifact(self.run_id, str(path)))
        )

    def close(self, failed: bool = False, killed: bool = False) -> None:
        status = "KILLED" if killed else "FAILED" if failed else "FINISHED"
        self.outbox.put(
            Request(f"the run's status {status}", send=lambda: self.client.set_terminated(self.run_id, status=status))
        )
        later = f"; send them with `gns track-sync {self.run_dir}` once it is back" if self.run_dir is not None else ""
        left = self.outbox.close(later)
        if left and self.run_dir is not None:
            write_text_atomic(
                RunFolder(self.run_dir).mlflow_unsent, json.dumps({"run_id": self.run_id, "status": status}) + "\n"
            )


def open_mlflow_tracker(run_dir: Path, tracking_uri: str, experiment: str, resume: bool) -> MlflowTracker:
    """The MLflow run of ``run_dir``: the one it logged to before when resuming there, else a new one."""
    validate_tracking_uri(tracking_uri)
    record = RunFolder(run_dir).mlflow_run
    kept_in = str(RunFolder(run_dir).metrics)
    if resume and record.is_file():
        try:
            saved = json.loads(record.read_text())
            if not isinstance(saved, dict):
                raise TypeError("not a JSON object")
        except (OSError, ValueError, TypeError) as exc:
            raise TrackingError(f"{record}: not a record of an MLflow run ({type(exc).__name__}: {exc})") from None
        if saved.get("tracking_uri") == tracking_uri and saved.get("experiment") == experiment:
            return MlflowTracker(tracking_uri, experiment, run_id=saved["run_id"], kept_in=kept_in, run_dir=run_dir)
    tracker = MlflowTracker(tracking_uri, experiment, run_name=Path(run_dir).name, kept_in=kept_in, run_dir=run_dir)
    record.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(
        record, json.dumps({"tracking_uri": tracking_uri, "experiment": experiment, "run_id": tracker.run_id}) + "\n"
    )
    return tracker


def log_to_recorded_run(
    run_dir: Path,
    metrics: dict[str, float],
    step: int,
    artifacts: Sequence[Path] = (),
    artifact_path: str | None = None,
    tags: dict[str, str] | None = None,
) -> str | None:
    """Add ``metrics`` (``artifacts`` under ``artifact_path``, and ``tags``) to the MLflow run that trained ``run_dir``.

    The run's status is left alone. Returns the run id, or None when the run was not
    tracked with MLflow (or mlflow is missing), or when its server is unreachable: the
    caller's results are on disk by then, so that is a warning, not a failure.
    """
    if not RunFolder(run_dir).mlflow_run.is_file() or not mlflow_available():
        return None
    try:
        saved = read_run_record(run_dir, validate_tracking_uri(default_tracking_uri()))
    except TrackingError as error:
        warnings.warn(f"tracking: {error}; nothing logged to MLflow", stacklevel=2)
        return None
    from mlflow.entities import Metric

    now = int(time.time() * 1000)
    entries = [Metric(k, float(v), now, step) for k, v in metrics.items() if math.isfinite(v)]
    client = _client(saved["tracking_uri"])
    try:
        client.log_batch(saved["run_id"], metrics=entries)
        for name, value in (tags or {}).items():
            client.set_tag(saved["run_id"], name, value)
        for artifact in artifacts:
            client.log_artifact(saved["run_id"], str(artifact), artifact_path)
    except Exception as error:
        if not server_unreachable(error):
            raise TrackingError(
                f"MLflow at {saved['tracking_uri']} refused run {saved['run_id']}: {first_line(error)}"
            ) from None
        warnings.warn(
            f"tracking: MLflow at {saved['tracking_uri']} unreachable ({first_line(error)}); "
            f"{', '.join(f'{k} {v:.6g}' for k, v in sorted(metrics.items()))} not logged to its run {saved['run_id']}",
            stacklevel=2,
        )
        return None
    return saved["run_id"]


def read_run_record(run_dir: Path, tracking_uri: str) -> dict:
    """The MLflow run record of ``run_dir`` when it names ``tracking_uri``, the user's store; else a TrackingError.

    The record is data: a run folder from elsewhere may name any store (another
    database, another server). Only the store the user configured is ever written to,
    so a record naming another one is refused, naming both. ``tracking_uri`` is
    validated by the caller (:func:`validate_tracking_uri`).
    """
    record = RunFolder(run_dir).mlflow_run
    try:
        saved = json.loads(record.read_text())
        uri, run_id = saved["tracking_uri"], saved["run_id"]
        if not isinstance(uri, str) or not isinstance(run_id, str):
            raise TypeError("tracking_uri and run_id must be strings")
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise TrackingError(f"{record}: not a record of an MLflow run ({type(exc).__name__}: {exc})") from None
    if uri != tracking_uri:
        raise TrackingError(
            f"{record}: the run was tracked in {uri}, but this command's store is {tracking_uri} "
            "(--tracking-uri, else $MLFLOW_TRACKING_URI, else ./mlflow.db); gns writes only to the store you name: "
            f"pass --tracking-uri {uri} if that is yours"
        )
    return saved


def _unsent_status(unsent: Path) -> str:
    """The status an unsent record says the run ended with: FINISHED, FAILED or KILLED."""
    try:
        status = json.loads(unsent.read_text()).get("status", "FINISHED")
    except (OSError, ValueError, AttributeError) as exc:
        raise TrackingError(f"{unsent}: not a record of what MLflow missed ({type(exc).__name__}: {exc})") from None
    if status not in ("FINISHED", "FAILED", "KILLED"):
        raise TrackingError(f"{unsent}: status {status!r}: expected FINISHED, FAILED or KILLED")
    return status


def sync_run(run_dir: Path, tracking_uri: str | None = None) -> tuple[str, int, str | None]:
    """Send ``run_dir``'s metrics.jsonl entries its MLflow run lacks, and the status it ended with.

    ``tracking_uri``: the user's store (default: $MLFLOW_TRACKING_URI, else ./mlflow.db);
    a run record naming another store is refused (:func:`read_run_record`).
    Returns (run id, metrics sent, status set or None). Refused with a TrackingError
    when the run was not tracked with MLflow, was tracked elsewhere, or its server is
    still unreachable.
    """
    from .tracking import read_metrics

    run_dir = Path(run_dir)
    record = RunFolder(run_dir).mlflow_run
    if not record.is_file():
        raise TrackingError(f"{run_dir}: no {RunFolder.MLFLOW_RUN}: this run was not tracked with MLflow")
    tracking_uri = validate_tracking_uri(tracking_uri or default_tracking_uri(), "--tracking-uri")
    saved = read_run_record(run_dir, tracking_uri)
    uri, run_id = saved["tracking_uri"], saved["run_id"]
    from mlflow.entities import Metric

    client = _client(uri)
    try:
        logged = client.get_run(run_id).data.metrics
        history = {key: {m.step for m in client.get_metric_history(run_id, key)} for key in logged}
        entries = []
        for line in read_metrics(run_dir):
            step, when = int(line.get("step", 0)), int(float(line.get("time", time.time())) * 1000)
            for key, value in line.items():
                if key in ("step", "time") or not isinstance(value, (int, float)) or not math.isfinite(value):
                    continue
                if step not in history.get(key, set()):
                    entries.append(Metric(key, float(value), when, step))
        for i in range(0, len(entries), METRICS_PER_REQUEST):
            client.log_batch(run_id, metrics=entries[i : i + METRICS_PER_REQUEST])
        status = None
        unsent = RunFolder(run_dir).mlflow_unsent
        if unsent.is_file():
            status = _unsent_status(unsent)
            client.set_terminated(run_id, status=status)
            unsent.unlink()
    except Exception as error:
        if not server_unreachable(error):
            raise TrackingError(f"MLflow at {uri} refused run {run_id}: {first_line(error)}") from None
        raise TrackingError(f"MLflow at {uri} is still unreachable ({first_line(error)}); try again later") from None
    return run_id, len(entries), status
