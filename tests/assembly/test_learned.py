"""assembly.learned: what training refuses of a recipe's components (an integrator that duplicates another)."""

from __future__ import annotations

import pytest

from gns_framework.assembly.learned import training_problems
from gns_framework.config.recipe import validate_recipe
from gns_framework.errors import RecipeError
from gns_framework.plugins import load_registry
from gns_framework.training.trainer import Trainer


def recipe(integrator: str):
    raw = {"name": "r", "dataset": {"path": "nowhere"}, "model": {"integrator": {"name": integrator}}}
    return validate_recipe(raw, load_registry())


@pytest.mark.parametrize("name", ["explicit_euler", "velocity_verlet"])
def test_an_integrator_with_another_ones_position_map_is_refused_for_training_naming_it(name):
    (problem,) = training_problems(recipe(name), load_registry())
    assert problem[0] == "model.integrator.name"
    assert f"{name!r} moves particles with 'semi_implicit_euler''s position map" in problem[1]
    assert "use 'semi_implicit_euler'" in problem[1]


@pytest.mark.parametrize("name", ["semi_implicit_euler", "velocity_euler"])
def test_integrators_with_their_own_position_map_train(name):
    assert training_problems(recipe(name), load_registry()) == []


def test_the_trainer_refuses_it_before_reading_any_data(tmp_path):
    with pytest.raises(RecipeError, match=r"model\.integrator\.name"):
        Trainer(recipe("explicit_euler"), load_registry(), run_dir=tmp_path / "run", progress=False)
    assert not (tmp_path / "run").exists()
