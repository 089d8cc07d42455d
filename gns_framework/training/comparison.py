"""Comparing tracked MLflow runs of any experiments: a table of chosen metrics and params, the recipe fields
that differ between the runs, and the metrics' curves.

Runs are picked by experiment name, by run id (or an unambiguous prefix of one, as the
table prints it) and by an MLflow search filter (``params.recipe.model.latent_size = '32'``,
``tags.team = 'geo'``), in any mix.
"""

from __future__ import annotations

import math
import string
from dataclasses import dataclass, field
from pathlib import Path

from .mlflow_tracker import TrackingError, _client, local_database

RECIPE_PREFIX = "recipe."
"""gns train logs the resolved recipe as params under this prefix (``recipe.model.latent_size``)."""
MAX_RUNS = 1000
MIN_ID_PREFIX = 8
"""The shortest run-id prefix accepted: the table prints the first 8 hex digits."""


@dataclass
class RunSummary:
    run_id: str
    name: str
    experiment: str
    status: str
    params: dict[str, str]
    """Every logged param of the run."""
    logged: set[str]
    """Names of every metric the run logged."""
    metrics: dict[str, float] = field(default_factory=dict)
    """Last logged value of each chosen metric."""
    histories: dict[str, list[tuple[int, float]]] = field(default_factory=dict)
    """(step, value) of each chosen metric."""


def param_value(params: dict[str, str], key: str) -> str | None:
    """``key`` as logged, or as a recipe key (``model.latent_size`` for ``recipe.model.latent_size``)."""
    return params.get(key, params.get(f"{RECIPE_PREFIX}{key}"))


def select_runs(
    tracking_uri: str, selectors: list[str], metrics: list[str], filter_string: str | None = None
) -> list[RunSummary]:
    """The runs named by ``selectors`` (experiment names, run ids or id prefixes), newest first.

    With ``filter_string`` only the runs matching that MLflow search filter are kept; with
    no selectors the filter is searched over every experiment. Each run comes once, with
    the histories of the chosen ``metrics`` it logged.
    """
    if not selectors and not filter_string:
        raise TrackingError("name at least one experiment or run, or give a filter")
    database = local_database(tracking_uri)
    if database is not None and not database.is_file():
        raise TrackingError(
            f"{tracking_uri}: no tracking database (train with gns train first, or pass --tracking-uri)"
        )
    client = _client(tracking_uri)
    experiments = {e.experiment_id: e.name for e in client.search_experiments()}
    by_name = {name: experiment_id for experiment_id, name in experiments.items()}

    chosen_experiments: list[str] = []
    named_runs: list = []
    for selector in selectors:
        if selector in by_name:
            chosen_experiments.append(by_name[selector])
        else:
            named_runs.append(_run_by_id(client, tracking_uri, selector, list(experiments), sorted(by_name)))
    runs = list(named_runs)
    if chosen_experiments or not selectors:
        runs += _search(client, chosen_experiments or list(experiments), None)
    if filter_string:
        involved = sorted({run.info.experiment_id for run in runs} | set(chosen_experiments or experiments))
        matching = {run.info.run_id for run in _search(client, involved, filter_string)}
        runs = [run for run in runs if run.info.run_id in matching]

    summaries, seen = [], set()
    for run in sorted(runs, key=lambda r: r.info.start_time or 0, reverse=True):
        if run.info.run_id in seen:
            continue
        seen.add(run.info.run_id)
        logged = set(run.data.metrics)
        summaries.append(
            RunSummary(
                run_id=run.info.run_id,
                name=run.info.run_name or run.info.run_id[:8],
                experiment=experiments.get(run.info.experiment_id, run.info.experiment_id),
                status=run.info.status,
                params=dict(run.data.params),
                logged=logged,
                metrics={key: run.data.metrics[key] for key in metrics if key in logged},
                histories={
                    key: [(m.step, m.value) for m in client.get_metric_history(run.info.run_id, key)]
                    for key in metrics
                    if key in logged
                },
            )
        )
    return summaries


def _search(client, experiment_ids: list[str], filter_string: str | None) -> list:
    from mlflow.exceptions import MlflowException

    if not experiment_ids:
        return []
    try:
        return list(client.search_runs(experiment_ids, filter_string or "", max_results=MAX_RUNS))
    except MlflowException as error:
        raise TrackingError(f"filter {filter_string!r}: {error.message}") from None


def _run_by_id(client, tracking_uri: str, selector: str, experiment_ids: list[str], names: list[str]):
    """The run whose id is ``selector`` or starts with it (at least MIN_ID_PREFIX hex digits, one run only)."""
    from mlflow.exceptions import MlflowException

    not_found = TrackingError(
        f"{tracking_uri}: no experiment or run {selector!r}; experiments: {', '.join(names) or 'none'} "
        f"(a run is named by its id, or by its first {MIN_ID_PREFIX} or more hex digits)"
    )
    if len(selector) < MIN_ID_PREFIX or not set(selector) <= set(string.hexdigits.lower()):
        raise not_found
    try:
        return client.get_run(selector)
    except MlflowException:
        pass
    found = [run for run in _search(client, experiment_ids, None) if run.info.run_id.startswith(selector)]
    if not found:
        raise not_found
    if len(found) > 1:
        raise TrackingError(
            f"run id prefix {selector!r} matches {len(found)} runs ({', '.join(r.info.run_id for r in found)}): "
            f"give more of the id"
        )
    return found[0]


def logged_metrics(runs: list[RunSummary]) -> list[str]:
    """Every metric name any of ``runs`` logged, sorted."""
    return sorted(set().union(*(run.logged for run in runs)))


def unlogged(runs: list[RunSummary], metrics: list[str]) -> list[str]:
    """The chosen ``metrics`` that none of ``runs`` logged."""
    known = set(logged_metrics(runs))
    return [metric for metric in metrics if metric not in known]


def differing_recipe_fields(runs: list[RunSummary]) -> list[str]:
    """The recipe keys (``model.latent_size``) whose logged value is not the same in every run, sorted.

    A field one run has and another lacks differs too (a component with other options).
    """
    keys = sorted({key for run in runs for key in run.params if key.startswith(RECIPE_PREFIX)})
    return [key[len(RECIPE_PREFIX) :] for key in keys if len({run.params.get(key) for run in runs}) > 1]


def sort_runs(runs: list[RunSummary], metric: str) -> list[RunSummary]:
    """Smallest ``metric`` first (losses and errors); runs without it last."""
    return sorted(runs, key=lambda r: (metric not in r.metrics, r.metrics.get(metric, math.inf)))


def format_table(runs: list[RunSummary], metrics: list[str], params: list[str]) -> str:
    """One row per run: name, experiment, id prefix, status, ``params`` (logged names or recipe keys), ``metrics``."""
    columns = ["run", "experiment", "id", "status", *params, *metrics]
    rows = [
        [r.name, r.experiment, r.run_id[:8], r.status.lower()]
        + [param_value(r.params, p) or "-" for p in params]
        + [f"{r.metrics[m]:.4g}" if m in r.metrics else "-" for m in metrics]
        for r in runs
    ]
    widths = [max(len(c), *(len(row[i]) for row in rows)) if rows else len(c) for i, c in enumerate(columns)]
    lines = ["  ".join(c.ljust(w) for c, w in zip(columns, widths, strict=True))]
    lines += ["  ".join(v.ljust(w) for v, w in zip(row, widths, strict=True)) for row in rows]
    return "\n".join(line.rstrip() for line in lines)


def plot_histories(runs: list[RunSummary], metrics: list[str], path: Path, title: str) -> Path:
    """One panel per metric, one curve per run (labelled experiment/run id), against the training step."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    figure, axes = plt.subplots(1, len(metrics), figsize=(5 * len(metrics), 3.8), squeeze=False)
    for axis, metric in zip(axes[0], metrics, strict=True):
        for run in runs:
            if run.histories.get(metric):
                steps, values = zip(*run.histories[metric], strict=True)
                axis.plot(steps, values, marker=".", label=f"{run.experiment}/{run.name} {run.run_id[:8]}")
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
