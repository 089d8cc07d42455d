"""Numbers in scene and recipe files are read as a user writes them (issue 19: ``3.537e5`` was a string)."""

from __future__ import annotations

import pytest

from gns_framework.config.recipe import load_recipe
from gns_framework.config.yaml_files import load_yaml_mapping
from gns_framework.errors import RecipeError
from gns_framework.ground_truth.scene_spec import load_scene


@pytest.mark.parametrize(
    "text, value",
    [
        ("3.537e5", 3.537e5),
        ("1e5", 1e5),
        ("-1E-3", -1e-3),
        ("+2.5e+4", 2.5e4),
        (".5e2", 50.0),
        ("2.e3", 2000.0),
        ("1_000.5e1", 10005.0),
        ("1.5", 1.5),
        ("-7", -7),
        (".inf", float("inf")),
    ],
)
def test_every_written_number_is_a_number(tmp_path, text, value):
    (tmp_path / "f.yaml").write_text(f"x: {text}\n")
    read = load_yaml_mapping(tmp_path / "f.yaml")["x"]
    assert not isinstance(read, str) and read == value


@pytest.mark.parametrize("text", ['"1e5"', "'3.5e5'", "1e5x", "e5", "1.2.3e4", "1e", "1e5.0"])
def test_quoted_and_non_numbers_stay_strings(tmp_path, text):
    (tmp_path / "f.yaml").write_text(f"x: {text}\n")
    assert isinstance(load_yaml_mapping(tmp_path / "f.yaml")["x"], str)


def test_scene_file_takes_exponent_numbers_and_keeps_numeric_looking_names(tmp_path):
    (tmp_path / "scene.yaml").write_text(
        "name: 1e5\n"
        "dim: 2\n"
        "domain: {bounds: [[0, 1], [0, 5e-1]], grid: 4e1}\n"
        "time: {frame_dt: 2.5e-3, substeps: 2e1, frames: 3}\n"
        "blocks:\n"
        "  - material: sand\n"
        "    position: [1e-1, 0]\n"
        "    size: [1e-1, 1e-1]\n"
        "    parameters: {youngs_modulus: 3.537e5, friction: {range: [5.8e-1, 8.4e-1]}}\n"
    )
    scene = load_scene(tmp_path / "scene.yaml")
    assert scene.name == "1e5"
    assert scene.domain.grid == 40 and scene.time.frame_dt == pytest.approx(2.5e-3)
    assert scene.blocks[0].parameters["youngs_modulus"].low == pytest.approx(3.537e5)
    assert scene.blocks[0].parameters["friction"].range == pytest.approx((0.58, 0.84))


def test_recipe_file_takes_exponent_numbers_and_keeps_numeric_looking_strings(tmp_path, registry):
    (tmp_path / "recipe.yaml").write_text(
        "name: 1e5\n"
        "dataset: {path: 2e3}\n"
        "model: {noise_std: 3e-4}\n"
        "training: {steps: 1e3, optimizer: {lr_init: 1e-4, lr_min: 1E-6}}\n"
    )
    recipe = load_recipe(tmp_path / "recipe.yaml", registry)
    assert recipe.name == "1e5" and recipe.dataset.path == "2e3"
    assert recipe.training.steps == 1000 and recipe.training.optimizer.lr_init == pytest.approx(1e-4)
    assert recipe.model.noise_std == pytest.approx(3e-4)
    assert isinstance(recipe.resolved()["training"]["optimizer"]["lr_min"], float)


@pytest.mark.parametrize(
    ("text", "where"),
    [
        ("a: " + "[" * 100_000 + "]" * 100_000 + "\n", "line 1, column 67"),
        ("a:\n" + "".join(" " * i + "b:\n" for i in range(1, 3000)), "line 65, column 65"),
    ],
)
def test_nesting_100000_deep_is_one_line_not_a_recursion_error(tmp_path, text, where):
    path = tmp_path / "deep.yaml"
    path.write_text(text)
    with pytest.raises(RecipeError) as error:
        load_yaml_mapping(path)
    assert str(error.value) == f"{path}: {where}: nested more than 64 levels deep; recipes and scenes nest a few levels"
