"""gns compare on a real local MLflow store: two experiments of different recipes, picked by name, run id and filter."""

from __future__ import annotations

import json
import struct

import pytest
from training_support import tiny_recipe, write_recipe

from gns_framework.cli import main
from gns_framework.io.run_folder import RunFolder

mlflow = pytest.importorskip("mlflow")


@pytest.fixture(scope="module")
def two_recipes(uneven_dataset, tmp_path_factory):
    """A store holding one run of recipe-a (latent 16, 4 steps) and one of recipe-b (latent 24, 2 steps),
    each in the experiment of its recipe's name."""
    root = tmp_path_factory.mktemp("compare")
    uri = f"sqlite:///{root / 'store.db'}"
    run_ids = {}
    for name, latent, steps in (("recipe-a", 16, 4), ("recipe-b", 24, 2)):
        recipe = tiny_recipe(uneven_dataset, name=name, steps=steps, validate_every=2, log_every=1)
        recipe["model"]["latent_size"] = latent
        recipe_file = write_recipe(root / f"{name}.yaml", recipe)
        run_dir = root / f"run-{name}"
        assert main(["train", str(recipe_file), "--out", str(run_dir), "--tracking-uri", uri, "--no-progress"]) == 0
        run_ids[name] = json.loads((run_dir / RunFolder.MLFLOW_RUN).read_text())["run_id"]
    return uri, run_ids, root


def compare(capsys, uri: str, *argv: str) -> tuple[int, list[str], str]:
    capsys.readouterr()
    code = main(["compare", *argv, "--tracking-uri", uri])
    captured = capsys.readouterr()
    return code, captured.out.splitlines(), captured.err


def table_rows(lines: list[str]) -> tuple[list[str], dict[str, dict[str, str]]]:
    """Header and ``{experiment: {column: value}}`` of the printed table (values hold no spaces here)."""
    header = lines[0].split()
    rows = [line.split() for line in lines[1:] if line and not line.endswith(".png")]
    return header, {row[1]: dict(zip(header, row, strict=True)) for row in rows}


def png_size(path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data.startswith(b"\x89PNG")
    return struct.unpack(">II", data[16:24])


def test_two_experiments_side_by_side_with_the_recipe_fields_that_differ(two_recipes, tmp_path, capsys):
    uri, run_ids, _ = two_recipes
    plot = tmp_path / "both.png"
    code, lines, err = compare(
        capsys,
        uri,
        "recipe-a",
        "recipe-b",
        "--metrics",
        "train_loss",
        "valid_one_step_position_mse",
        "--plot",
        str(plot),
    )
    assert code == 0, err
    header, rows = table_rows(lines)
    assert header[:5] == ["run", "experiment", "id", "status", "world_size"]
    assert header[-2:] == ["train_loss", "valid_one_step_position_mse"]
    differing = header[5:-2]
    assert {"name", "model.latent_size", "training.steps"} <= set(differing)
    assert "model.mlp_hidden_size" not in differing and "seed" not in differing  # the same in both recipes
    assert set(rows) == {"recipe-a", "recipe-b"}
    assert rows["recipe-a"]["model.latent_size"] == "16" and rows["recipe-b"]["model.latent_size"] == "24"
    assert rows["recipe-a"]["training.steps"] == "4" and rows["recipe-b"]["training.steps"] == "2"
    assert rows["recipe-a"]["id"] == run_ids["recipe-a"][:8]
    assert all(float(row["train_loss"]) > 0 for row in rows.values())
    assert "2 runs of 2 experiment(s) (recipe-a, recipe-b)" in lines[-1]
    assert png_size(plot)[0] == 2 * 500  # one 5-inch panel per metric at 100 dpi


def test_runs_picked_by_id_prefix_and_by_filters(two_recipes, tmp_path, capsys):
    uri, run_ids, _ = two_recipes
    plot = tmp_path / "picked.png"
    code, lines, err = compare(capsys, uri, run_ids["recipe-a"][:8], run_ids["recipe-b"], "--plot", str(plot))
    assert code == 0, err
    assert set(table_rows(lines)[1]) == {"recipe-a", "recipe-b"}

    code, lines, err = compare(capsys, uri, "--filter", "params.recipe.model.latent_size = '24'", "--plot", str(plot))
    assert code == 0, err
    assert set(table_rows(lines)[1]) == {"recipe-b"}

    mlflow.tracking.MlflowClient(uri).set_tag(run_ids["recipe-a"], "team", "geo")
    code, lines, err = compare(
        capsys, uri, "recipe-a", "recipe-b", "--filter", "tags.team = 'geo'", "--plot", str(plot)
    )
    assert code == 0, err
    assert set(table_rows(lines)[1]) == {"recipe-a"}


def test_unknown_metrics_are_named_with_the_logged_ones(two_recipes, tmp_path, capsys):
    uri, _, _ = two_recipes
    plot = tmp_path / "one.png"
    code, lines, err = compare(
        capsys, uri, "recipe-a", "recipe-b", "--metrics", "train_los", "train_loss", "--plot", str(plot)
    )
    assert code == 0, err
    assert "no run logged metric 'train_los'; logged metrics: " in err
    assert "train_loss" in err.split("logged metrics: ")[1] and "steps_per_s" in err.split("logged metrics: ")[1]
    assert table_rows(lines)[0][-1] == "train_loss" and "train_los" not in table_rows(lines)[0]
    assert png_size(plot)[0] == 500  # the unknown metric gets no empty panel

    code, _, err = compare(capsys, uri, "recipe-a", "--metrics", "nothing", "--plot", str(plot))
    assert code == 2 and "none of the metrics nothing was logged" in err


def test_unknown_names_and_bad_filters_are_clear_errors(two_recipes, tmp_path, capsys):
    uri, _run_ids, _ = two_recipes
    code, _, err = compare(capsys, uri, "recipe-c")
    assert code == 2 and "no experiment or run 'recipe-c'; experiments: Default, recipe-a, recipe-b" in err
    code, _, err = compare(capsys, uri, "recipe-a", "--filter", "params.x ==== 1")
    assert code == 2 and "filter 'params.x ==== 1'" in err
    code, _, err = compare(capsys, uri, "recipe-a", "--filter", "tags.team = 'nobody'")
    assert code == 2 and "no runs match" in err
