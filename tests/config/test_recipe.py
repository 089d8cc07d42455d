"""Recipe validation: every shipped recipe, all problems at once, locations, did-you-mean."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from gns_framework.config.recipe import load_recipe, validate_recipe
from gns_framework.errors import RecipeError

RECIPES = sorted((Path(__file__).resolve().parents[2] / "recipes").rglob("*.yaml"))
NEEDS_PACKAGE = {
    "clay2d.yaml": ("gns_example_clay", "pip install -e plugins/examples/gns-clay"),
    "mean_interaction_network.yaml": ("gns_example_processor", "pip install -e plugins/examples/gns-processor"),
}
"""Recipes that use a separately installed example package: its module and install command."""


def _shipped(path: Path):
    needed = NEEDS_PACKAGE.get(path.name)
    missing = needed is not None and importlib.util.find_spec(needed[0]) is None
    marks = [pytest.mark.skip(reason=f"needs {needed[0]}: {needed[1]}")] if missing else []
    return pytest.param(path, marks=marks, id=str(path.relative_to(path.parents[1])))


def test_recipes_exist():
    names = {p.name for p in RECIPES}
    assert {"water2d.yaml", "sand2d.yaml", "sand3d.yaml"} <= names


@pytest.mark.parametrize("path", [_shipped(p) for p in RECIPES])
def test_every_shipped_recipe_validates(path, registry):
    recipe = load_recipe(path, registry)
    assert recipe.name


def _write(tmp_path, text):
    path = tmp_path / "recipe.yaml"
    path.write_text(text)
    return path


def test_three_mistakes_are_reported_at_once_with_locations(tmp_path, registry):
    path = _write(
        tmp_path,
        """
name: broken
dataset: {path: data/x}
model:
  latent_size: -3
  procesor: {name: interaction_network}
training:
  steps: 10
  optimizer: {lr_init: 1e-4, lr_decay_step: 100}
""",
    )
    with pytest.raises(RecipeError) as info:
        load_recipe(path, registry)
    problems = dict(info.value.problems)
    assert len(info.value.problems) == 3
    assert "model.latent_size" in problems
    assert "did you mean 'processor'" in problems["model.procesor"]
    assert "did you mean 'lr_decay_steps'" in problems["training.optimizer.lr_decay_step"]
    assert str(path) in str(info.value)


def test_unknown_component_lists_installed_choices(registry):
    raw = {
        "name": "x",
        "dataset": {"path": "d"},
        "model": {"processor": {"name": "gnn"}, "integrator": {"name": "euler_semi"}},
    }
    with pytest.raises(RecipeError) as info:
        validate_recipe(raw, registry, "r.yaml")
    problems = dict(info.value.problems)
    assert "interaction_network" in problems["model.processor.name"].split("installed: ")[1].split(", ")
    assert "semi_implicit_euler" in problems["model.integrator.name"]


def test_component_params_are_validated_with_their_location(registry):
    raw = {
        "name": "x",
        "dataset": {"path": "d", "verify_checksum": True, "name": "tfrecord"},
        "model": {"processor": {"name": "interaction_network", "message_passing_steps": 0}},
    }
    with pytest.raises(RecipeError) as info:
        validate_recipe(raw, registry)
    problems = dict(info.value.problems)
    assert "did you mean 'verify_checksums'" in problems["dataset.verify_checksum"]
    assert "greater than or equal to 1" in problems["model.processor.message_passing_steps"]


def test_a_recipe_cannot_grant_unpickling(registry):
    """The grant would travel with the recipe and its checkpoints to other data: it is given per command instead."""
    for value in (True, False):
        raw = {"name": "x", "dataset": {"name": "npz", "path": "d", "allow_pickle": value}}
        with pytest.raises(RecipeError) as info:
            validate_recipe(raw, registry, "r.yaml")
        assert [location for location, _ in info.value.problems] == ["dataset.allow_pickle"]
        assert "--allow-pickle FOLDER" in str(info.value)


def test_unknown_material_is_reported(registry):
    raw = {"name": "x", "dataset": {"path": "d"}, "model": {"materials": ["watr"]}}
    with pytest.raises(RecipeError, match=r"model.materials\[0\].*did you mean 'water'"):
        validate_recipe(raw, registry)


def test_yaml_syntax_error_names_line(tmp_path, registry):
    path = _write(tmp_path, "name: x\ndataset: {path: d\nmodel: {}\n")
    with pytest.raises(RecipeError, match="line"):
        load_recipe(path, registry)


def test_duplicate_keys_are_errors(tmp_path, registry):
    path = _write(tmp_path, "name: x\nname: y\ndataset: {path: d}\n")
    with pytest.raises(RecipeError, match="duplicate key 'name'"):
        load_recipe(path, registry)
