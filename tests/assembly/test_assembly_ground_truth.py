"""A ground-truth simulator from a scene (``gns_framework.assembly.ground_truth``): the simulator the scene names,
with its parameters and every installed material; a scene it cannot simulate refused with every problem at once,
located in the scene file, before anything runs."""

from __future__ import annotations

import pytest
from scene_builders import column_collapse

from gns_framework.assembly.ground_truth import build_ground_truth_simulator
from gns_framework.errors import RecipeError
from gns_framework.ground_truth.scene_spec import parse_scene


def scene_of(**changes):
    raw = column_collapse(0.1, 0.1, 0.6, frames=4)
    raw.update(changes)
    return parse_scene(raw)


def test_the_scenes_simulator_with_its_parameters_and_every_material(sim_registry):
    simulator = build_ground_truth_simulator(scene_of(simulator={"name": "mls_mpm", "cfl": 0.3}), sim_registry)
    assert type(simulator) is sim_registry.get("simulator", "mls_mpm")
    assert simulator.params.cfl == 0.3
    # Every installed material, not only the scene's sand: a simulator is shared across scenes.
    assert set(simulator.materials) == set(sim_registry.names("material"))
    assert simulator.materials["sand"] is sim_registry.get("material", "sand")


def test_an_unknown_simulator_or_parameter_is_located_in_the_scene_file(sim_registry):
    with pytest.raises(RecipeError) as caught:
        build_ground_truth_simulator(scene_of(simulator={"name": "sph"}), sim_registry, "scene.yaml")
    assert caught.value.source == "scene.yaml"
    ((location, message),) = caught.value.problems
    assert location == "simulator.name" and "'sph'" in message and "mls_mpm" in message
    with pytest.raises(RecipeError) as caught:
        build_ground_truth_simulator(scene_of(simulator={"name": "mls_mpm", "cfl": 2.0}), sim_registry, "scene.yaml")
    assert [location for location, _ in caught.value.problems] == ["simulator.cfl"]


def test_what_the_simulator_cannot_simulate_is_refused_with_every_problem(sim_registry):
    raw = column_collapse(0.1, 0.1, 0.6, frames=4)
    raw["blocks"].append({"material": "lava", "position": [0.3, 0.0], "size": [0.05, 0.05]})
    raw["blocks"].append({"material": "magma", "position": [0.5, 0.0], "size": [0.05, 0.05]})
    with pytest.raises(RecipeError) as caught:
        build_ground_truth_simulator(parse_scene(raw), sim_registry, "scene.yaml")
    problems = dict(caught.value.problems)
    assert caught.value.source == "scene.yaml"
    assert problems["blocks[1].material"].startswith("unknown material 'lava'")
    assert problems["blocks[2].material"].startswith("unknown material 'magma'")
