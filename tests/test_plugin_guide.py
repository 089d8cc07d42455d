"""The plugin author's guide is enough: its processor is the tested example package's code as it is, its
material, written from the guide alone, is simulated by the built-in MLS-MPM in the guide's scene, and its
metric and command examples work as written."""

from __future__ import annotations

import dataclasses
import re
import types
from pathlib import Path

import numpy as np
import pytest
import yaml

from gns_framework import testing
from gns_framework.assembly.ground_truth import build_ground_truth_simulator
from gns_framework.evaluation.candidates import granular_particle_types
from gns_framework.evaluation.report import score_rollout
from gns_framework.ground_truth.scene_spec import SceneSpec
from gns_framework.plugins import load_registry
from gns_framework.testing import small_scene

REPO = Path(__file__).resolve().parents[1]
GUIDE = REPO / "docs" / "plugin-authors.md"
EXAMPLE_PROCESSOR = REPO / "plugins" / "examples" / "gns-processor"


def guide_block(after: str, language: str = "python") -> str:
    """The first ``language`` block of the guide after the line ``after``."""
    text = GUIDE.read_text()
    start = text.index(after)
    return re.search(rf"```{language}\n(.*?)```", text[start:], re.S).group(1)


def guide_module(name: str, after: str) -> types.ModuleType:
    module = types.ModuleType(name)
    exec(compile(guide_block(after), f"{GUIDE}:{name}", "exec"), module.__dict__)
    return module


@pytest.fixture(scope="module")
def gravel_registry():
    return load_registry(plugins=[("guide-gravel", guide_module("guide_gravel", "<!-- guide-material -->"))])


def test_the_guide_material_conforms_and_is_granular(gravel_registry):
    gravel = gravel_registry.get("material", "gravel")
    testing.check_material(gravel)
    scene = dataclasses.replace(small_scene(2), particle_types=(3, gravel.particle_type), kinematic_types=(3,))
    assert granular_particle_types(scene, gravel_registry) == [gravel.particle_type]


def test_the_guide_material_is_simulated_by_the_builtin_mpm(gravel_registry):
    raw = {
        "name": "gravel_column",
        "dim": 2,
        "domain": {"bounds": [[0.0, 0.4], [0.0, 0.4]], "grid": 16},
        "time": {"frame_dt": 0.0025, "substeps": 10, "frames": 8},
        "blocks": [
            {
                "material": "gravel",
                "position": [0.0, 0.0],
                "size": [0.1, 0.15],
                "properties": {"friction": {"range": [0.6, 0.8]}},
            }
        ],
    }
    scene = SceneSpec.model_validate(raw)
    build_ground_truth_simulator(scene, gravel_registry, "<guide scene>")  # every shared and MPM check passes
    materials = {name: gravel_registry.get("material", name) for name in gravel_registry.names("material")}
    testing.check_simulator(gravel_registry.get("simulator", "mls_mpm"), scene, materials)
    trajectory = build_ground_truth_simulator(scene, gravel_registry).simulate(scene, seed=0)
    assert set(trajectory.particle_type.tolist()) == {9}
    assert trajectory.position[-1, :, 1].mean() < trajectory.position[0, :, 1].mean()  # the column slumps


def test_the_guide_metric_is_measured(make_rollout_2d):
    registry = load_registry(plugins=[("guide-metric", guide_module("guide_metric", "## 6. Metrics"))])
    summary = score_rollout(make_rollout_2d, metrics=registry.metrics())
    truth, predicted = make_rollout_2d.ground_truth, make_rollout_2d.predicted
    moving = make_rollout_2d.particle_type != 3
    expected = abs(predicted[-1, moving, -1].max() - truth[-1, moving, -1].max())
    assert summary["final_height_error"] == pytest.approx(float(expected), rel=1e-5)


@pytest.fixture
def make_rollout_2d():
    from gns_framework.data.metadata import DatasetMetadata
    from gns_framework.data.rollout import Rollout
    from gns_framework.data.trajectory import Trajectory

    rng = np.random.default_rng(0)
    truth = rng.uniform(0.2, 0.8, size=(5, 6, 2))
    predicted = truth + rng.normal(0, 0.01, size=truth.shape)
    metadata = DatasetMetadata(
        bounds=[(0.0, 1.0)] * 2,
        sequence_length=11,
        default_connectivity_radius=0.1,
        dim=2,
        dt=0.01,
        vel_mean=[0.0] * 2,
        vel_std=[1.0] * 2,
        acc_mean=[0.0] * 2,
        acc_std=[1.0] * 2,
    )
    types_ = np.array([6, 6, 6, 6, 3, 3])
    frames = np.concatenate([truth[:1].repeat(6, 0), truth]).astype(np.float32)
    return Rollout(Trajectory(frames, types_), predicted.astype(np.float32), 6, metadata)


def test_the_guide_command_record_registers():
    from gns_framework.cli.commands import load_commands

    guide_commands = guide_module("guide_cmd", "## 7. Commands")
    commands = load_commands(load_entry_points=False, plugins=[("guide-commands", guide_commands)])
    assert commands["sieve"].module == "my_gns_plugin.sieve" and "train" in commands


@pytest.mark.parametrize(
    "marker, language, path",
    [
        ("example-processor", "python", "src/gns_example_processor/mean_interaction.py"),
        ("example-processor-hook", "python", "src/gns_example_processor/__init__.py"),
        ("example-processor-pyproject", "toml", "pyproject.toml"),
        ("example-processor-tests", "python", "tests/test_mean_interaction.py"),
    ],
)
def test_the_guide_shows_the_example_processors_files_as_they_are(marker, language, path):
    assert guide_block(f"<!-- {marker} -->", language) == (EXAMPLE_PROCESSOR / path).read_text()


def test_the_guides_recipe_line_is_the_swap_recipes_and_selects_the_processor(registry):
    from gns_framework.config.recipe import load_recipe

    pytest.importorskip("gns_example_processor", reason="install it: pip install -e plugins/examples/gns-processor")
    line = guide_block("<!-- example-processor-recipe -->", "yaml")
    swap = REPO / "recipes" / "swaps" / "mean_interaction_network.yaml"
    assert line in swap.read_text()
    processor = load_recipe(swap, registry).model.processor
    assert (processor.name, processor.params) == ("mean_interaction_network", {"message_passing_steps": 10})


def test_the_guide_scene_is_simulated_with_the_guide_material(gravel_registry):
    raw = yaml.safe_load(guide_block("<!-- guide-scene -->", "yaml"))
    scene = SceneSpec.model_validate(raw)
    build_ground_truth_simulator(scene, gravel_registry, "<guide scene>")  # every shared and MPM check passes
    short = scene.model_copy(update={"time": scene.time.model_copy(update={"frames": 4})})
    trajectory = build_ground_truth_simulator(short, gravel_registry).simulate(short, seed=0)
    types = trajectory.particle_type.tolist()
    assert set(types) == {3, 9} and types.count(9) == 512  # the comment's count of gravel particles
    assert trajectory.material_property.shape == (len(types), 1)  # friction, drawn for the trajectory


def test_the_guides_whole_recipe_is_the_clay_swap_recipe_and_validates(registry):
    """The complete recipe the guide gives is recipes/swaps/clay2d.yaml field for field, and trains as it is."""
    from gns_framework.config.recipe import validate_recipe

    pytest.importorskip("gns_example_clay", reason="install it: pip install -e plugins/examples/gns-clay")
    guide = yaml.safe_load(guide_block("<!-- guide-whole-recipe -->", "yaml"))
    shipped = yaml.safe_load((REPO / "recipes" / "swaps" / "clay2d.yaml").read_text())
    assert {k: v for k, v in guide.items() if k != "description"} == {
        k: v for k, v in shipped.items() if k != "description"
    }
    recipe = validate_recipe(guide, registry)
    assert recipe.model.materials == ["clay", "rigid"] and recipe.model.material_properties == ["cohesion"]
