"""gns check refuses what training would refuse, every problem at once with its location (issue 31, item 2)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import yaml
from tiny import tiny_recipe_mapping

from gns_framework.cli import main
from gns_framework.cli.check import check_recipe
from gns_framework.config.recipe import load_recipe
from gns_framework.errors import RecipeError

ROOT = Path(__file__).resolve().parents[2]


def write(path: Path, raw: dict) -> Path:
    path.write_text(yaml.safe_dump(raw))
    return path


def problems_of(file: Path, registry) -> dict[str, str]:
    with pytest.raises(RecipeError) as caught:
        check_recipe(file, registry)
    assert str(file) in str(caught.value)
    return dict(caught.value.problems)


def test_a_trainable_recipe_is_ok(tmp_path, dataset_multimaterial, capsys):
    recipe = write(tmp_path / "tiny.yaml", tiny_recipe_mapping(dataset_multimaterial))
    assert main(["check", str(recipe)]) == 0
    assert f"{recipe}: ok" in capsys.readouterr().out


def test_a_missing_dataset_folder_is_refused(tmp_path, registry, capsys):
    recipe = write(tmp_path / "r.yaml", tiny_recipe_mapping(tmp_path / "no_such_data"))
    found = problems_of(recipe, registry)
    assert "dataset folder not found" in found["dataset.path"] and "no_such_data" in found["dataset.path"]
    assert main(["check", str(recipe)]) == 1
    assert "dataset.path: " in capsys.readouterr().err
    assert main(["check", "--no-data", str(recipe)]) == 0  # the recipe alone is valid


def test_a_folder_without_the_layouts_files_is_refused(tmp_path, registry):
    (tmp_path / "empty").mkdir()
    recipe = write(tmp_path / "r.yaml", tiny_recipe_mapping(tmp_path / "empty"))
    assert "metadata.json" in problems_of(recipe, registry)["dataset.path"]


def test_materials_that_do_not_cover_the_datas_type_ids_are_refused(tmp_path, dataset_multimaterial, registry):
    # The data holds water (5), sand (6) and a rigid floor (3).
    recipe = write(tmp_path / "r.yaml", tiny_recipe_mapping(dataset_multimaterial, materials=["sand", "rigid"]))
    found = problems_of(recipe, registry)
    assert "ids [5] belong to no material of the model (sand, rigid)" in found["model.materials"]


def test_a_graph_builder_whose_optional_module_is_missing_is_refused(
    tmp_path, dataset_multimaterial, registry, monkeypatch
):
    monkeypatch.setitem(sys.modules, "torch_cluster", None)  # not importable, installed or not
    raw = tiny_recipe_mapping(tmp_path / "no_such_data", graph_builder={"name": "radius_torch_cluster"})
    found = problems_of(write(tmp_path / "r.yaml", raw), registry)
    message = found["model.graph_builder.name"]
    assert "'radius_torch_cluster' needs the optional module 'torch_cluster'" in message
    assert "dataset.path" in found  # every problem at once
    # Any component class may declare its optional modules.
    builder = registry.get("graph_builder", "radius")
    monkeypatch.setattr(builder, "optional_modules", ("gns_no_such_module",), raising=False)
    raw = tiny_recipe_mapping(dataset_multimaterial, graph_builder={"name": "radius"})
    found = problems_of(write(tmp_path / "r2.yaml", raw), registry)
    assert "'gns_no_such_module'" in found["model.graph_builder.name"]


def test_trajectories_too_short_for_the_history_are_refused(tmp_path, dataset_multimaterial, registry):
    recipe = write(tmp_path / "r.yaml", tiny_recipe_mapping(dataset_multimaterial, history=30))
    assert "no trajectory has more than history" in problems_of(recipe, registry)["model.history"]


SHIPPED = sorted((ROOT / "recipes").rglob("*.yaml"))


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: str(p.relative_to(ROOT)))
def test_the_shipped_recipes_whose_data_exists_are_ok(path, registry, monkeypatch):
    monkeypatch.chdir(ROOT)
    recipe = load_recipe(path, registry)
    if not Path(recipe.dataset.path).is_dir():
        pytest.skip(f"{recipe.dataset.path} is not generated here")
    if any(
        getattr(registry.get(kind, getattr(recipe.model, kind).name), "optional_modules", ())
        for kind in ("graph_builder",)
    ):
        pytest.importorskip("torch_cluster")
    check_recipe(path.relative_to(ROOT), registry)
