"""Comparing the tracked runs of an MLflow experiment: a table of chosen metrics and params, and their curves."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from .mlflow_tracker import TrackingError, _client, experiment_id, local_database


@dataclass
class RunSummary:
    run_id: str
    name: str
    status: str
    params: dict[str, str]
    metrics: dict[str, float]
    """Last logged value of each chosen metric."""
    histories: dict[str, list[tuple[int, float]]] = field(default_factory=dict)
    """(step, value) of each chosen metric."""


def param_value(params: dict[str, str], key: str) -> str | None:
    """``key`` as logged, or as a recipe key (``model.latent_size`` for ``recipe.model.latent_size``)."""
    return params.get(key, params.get(f"recipe.{key}"))


def experiment_runs(tracking_uri: str, experiment: str, metrics: list[str], params: list[str]) -> list[RunSummary]:
    """The runs of ``experiment``, newest first, with the chosen metrics' histories."""
    database = local_database(tracking_uri)
    if database is not None and not database.is_file():
        raise TrackingError(f"{tracking_uri}: no tracking database (train with gns train first, or pass --tracking-uri)")
    client = _client(tracking_uri)
    found = experiment_id(client, tracking_uri, experiment, create=False)
    if found is None:
        names = sorted(e.name for e in client.search_experiments())
        raise TrackingError(f"{tracking_uri}: no experiment {experiment!r}; experiments: {', '.join(names) or 'none'}")
    runs = client.search_runs([found], max_results=1000, order_by=["attributes.start_time DESC"])
    summaries = []
    for run in runs:
        histories = {
            key: [(m.step, m.value) for m in client.get_metric_history(run.info.run_id, key)]
            for key in metrics
            if key in run.data.metrics
        }
        summaries.append(
            RunSummary(
                run_id=run.info.run_id,
                name=run.info.run_name or run.info.run_id[:8],
                status=run.info.status,
                params={key: value for key in params if (value := param_value(run.data.params, key)) is not None},
                metrics={key: run.data.metrics[key] for key in metrics if key in run.data.metrics},
                histories=histories,
            )
        )
    return summaries


def sort_runs(runs: list[RunSummary], metric: str) -> list[RunSummary]:
    """Smallest ``metric`` first (losses and errors); runs without it last."""
    return sorted(runs, key=lambda r: (metric not in r.metrics, r.metrics.get(metric, math.inf)))


def format_table(runs: list[RunSummary], metrics: list[str], params: list[str]) -> str:
    columns = ["run", "id", "status", *params, *metrics]
    rows = [
        [r.name, r.run_id[:8], r.status.lower()]
        + [r.params.get(p, "-") for p in params]
        + [f"{r.metrics[m]:.4g}" if m in r.metrics else "-" for m in metrics]
        for r in runs
    ]
    widths = [max(len(c), *(len(row[i]) for row in rows)) if rows else len(c) for i, c in enumerate(columns)]
    lines = ["  ".join(c.ljust(w) for c, w in zip(columns, widths))]
    lines += ["  ".join(v.ljust(w) for v, w in zip(row, widths)) for row in rows]
    return "\n".join(line.rstrip() for line in lines)


def plot_histories(runs: list[RunSummary], metrics: list[str], path: Path, title: str) -> Path:
    """One panel per metric, one curve per run, against the training step."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    figure, axes = plt.subplots(1, len(metrics), figsize=(5 * len(metrics), 3.8), squeeze=False)
    for axis, metric in zip(axes[0], metrics):
        for run in runs:
            if run.histories.get(metric):
                steps, values = zip(*run.histories[metric])
                axis.plot(steps, values, marker=".", label=f"{run.name} {run.run_id[:8]}")
        axis.set_title(metric)
        axis.set_xlabel("step")
        if all(v > 0 for r in runs for _, v in r.histories.get(metric, [])):
            axis.set_yscale("log")
    axes[0][0].legend(fontsize="small")
    figure.suptitle(title)
    figure.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=100)
    plt.close(figure)
    return path
