"""``gns compare`` (``gns_framework.cli.compare``): which metrics, params and sort the table gets, the errors when
nothing can be shown, and the default plot name. The runs come from a stand-in for the MLflow search here; the
command on a real MLflow store is tested in tests/training/test_comparison.py."""

from __future__ import annotations

from pathlib import Path

import pytest

from gns_framework.cli import main
from gns_framework.cli.compare import default_plot_name
from gns_framework.training import comparison
from gns_framework.training.comparison import RunSummary


def summary(run_id: str, experiment: str, loss: float, latent: str, **extra_params) -> RunSummary:
    params = {"world_size": "1", "recipe.model.latent_size": latent, "recipe.seed": "0", **extra_params}
    return RunSummary(run_id, f"run-{run_id[:2]}", experiment, "FINISHED", params, {"train_loss"}, {"train_loss": loss})


RUNS = [
    summary("aa" * 16, "sand", 0.5, "16"),
    summary("bb" * 16, "water", 0.2, "32", **{"recipe.training.steps": "10"}),
]


@pytest.fixture
def store(monkeypatch):
    """``gns compare`` on RUNS: what it asked for and what it plotted."""
    seen = {}

    def select_runs(uri, selectors, metrics, filter_string):
        seen["select"] = (uri, selectors, metrics, filter_string)
        return list(RUNS) if selectors != ["nothing"] else []

    def plot_histories(runs, metrics, path, title):
        seen["plot"] = ([run.run_id for run in runs], metrics, path, title)
        return path

    monkeypatch.setattr(comparison, "select_runs", select_runs)
    monkeypatch.setattr(comparison, "plot_histories", plot_histories)
    return seen


def compare(capsys, *argv: str) -> tuple[int, list[str], str]:
    code = main(["compare", *argv, "--tracking-uri", "sqlite:///unused.db"])
    captured = capsys.readouterr()
    return code, captured.out.splitlines(), captured.err


def test_the_table_adds_the_differing_recipe_fields_and_sorts_by_the_first_logged_metric(store, capsys):
    code, lines, err = compare(capsys, "sand", "water", "--metrics", "valid_loss", "train_loss", "--plot")
    assert code == 0, err
    # valid_loss is named but no run logged it: a warning listing what was logged, and no column for it.
    assert err.strip() == "gns compare: warning: no run logged metric 'valid_loss'; logged metrics: train_loss"
    header = lines[0].split()
    # --params (default world_size), then the recipe fields whose values differ (seed is the same in both).
    assert header == [
        "run",
        "experiment",
        "id",
        "status",
        "world_size",
        "model.latent_size",
        "training.steps",
        "train_loss",
    ]
    # Sorted by train_loss, smallest first: water (0.2) above sand (0.5).
    assert [line.split()[1] for line in lines[1:3]] == ["water", "sand"]
    assert lines[2].split()[-2:] == ["-", "0.5"]  # sand logged no training.steps
    assert store["select"] == ("sqlite:///unused.db", ["sand", "water"], ["valid_loss", "train_loss"], None)
    _ids, metrics, path, title = store["plot"]
    assert metrics == ["train_loss"] and path == Path("compare-sand.water-train_loss.png") and title == "sand water"
    assert lines[-1] == "2 runs of 2 experiment(s) (sand, water); plot in compare-sand.water-train_loss.png"


def test_a_param_asked_for_is_not_repeated_among_the_differing_fields(store, capsys):
    code, lines, _ = compare(capsys, "sand", "water", "--metrics", "train_loss", "--params", "model.latent_size")
    assert code == 0
    assert lines[0].split()[4:] == ["model.latent_size", "training.steps", "train_loss"]


@pytest.mark.parametrize(
    "argv, message",
    [
        (["nothing", "--filter", "tags.team = 'geo'"], "no runs match nothing tags.team = 'geo'"),
        (["sand", "--metrics", "valid_loss"], "none of the metrics valid_loss was logged by these runs"),
        (["sand", "--sort", "valid_loss"], "--sort valid_loss: no run logged it; logged metrics: train_loss"),
    ],
)
def test_nothing_to_show_is_a_one_line_error_before_any_plot(store, capsys, argv, message):
    code, _, err = compare(capsys, *argv)
    # Warnings for the unlogged metrics may come first; the error is the last line.
    assert code == 2 and err.strip().splitlines()[-1] == f"gns compare: error: {message}"
    assert "plot" not in store


def test_the_default_plot_name_says_what_it_compares_and_stays_one_short_name():
    assert default_plot_name(["sand"], ["train_loss", "steps_per_s"]) == Path("compare-sand-train_loss.steps_per_s.png")
    many = [f"experiment-{i}" for i in range(12)]
    # Past 120 characters only the first experiment and metric are named; ".more" says others were compared.
    assert default_plot_name(many, ["train_loss", "steps_per_s"]) == Path(
        "compare-experiment-0.more-train_loss.more.png"
    )
    assert default_plot_name(many, ["train_loss"]) == Path("compare-experiment-0.more-train_loss.png")
    # An experiment name from the store is never a path: the plot stays in the working directory.
    odd = default_plot_name(["../team/sand"], ["train_loss"])
    assert odd.parent == Path(".") and "/" not in odd.name and odd.suffix == ".png"


def test_by_default_the_validation_rollout_metrics_are_shown_silently_without_those_not_logged_and_no_file(
    store, capsys, tmp_path, monkeypatch
):
    """Issue 48: recipes are compared on their validation rollouts; defaults the runs did not log are no warning;
    without --plot nothing is written."""
    from gns_framework.cli.compare import DEFAULT_METRICS

    monkeypatch.chdir(tmp_path)
    code, lines, err = compare(capsys, "sand", "water")
    assert code == 0 and err == ""
    assert {"valid_rollout_mse", "valid_rollout_sinkhorn_pct"} <= set(DEFAULT_METRICS)
    assert store["select"][2] == DEFAULT_METRICS and lines[0].split()[-1] == "train_loss"
    assert "plot" not in store and lines[-1] == "2 runs of 2 experiment(s) (sand, water)"
    assert list(tmp_path.iterdir()) == []
