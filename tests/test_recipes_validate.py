"""Every recipe under recipes/ (recursively) validates against the installed components."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from gns_framework.plugins import load_registry
from gns_framework.recipe import load_recipe

RECIPES = Path(__file__).resolve().parents[1] / "recipes"
NEEDS = {"swaps/clay2d.yaml": "gns_example_clay"}
"""Recipes that use a component of a separately installed package, and that package."""


def recipe_files():
    for path in sorted(RECIPES.rglob("*.y*ml")):
        relative = path.relative_to(RECIPES).as_posix()
        needed = NEEDS.get(relative)
        marks = []
        if needed and importlib.util.find_spec(needed) is None:
            marks.append(pytest.mark.skip(reason=f"needs {needed}: pip install -e plugins/examples/gns-clay"))
        yield pytest.param(path, marks=marks, id=relative)


def test_recipes_exist():
    assert len(list(RECIPES.rglob("*.y*ml"))) >= 13


@pytest.mark.parametrize("path", recipe_files())
def test_recipe_validates(path):
    load_recipe(path, load_registry())
