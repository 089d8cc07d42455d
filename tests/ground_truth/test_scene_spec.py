"""Scene specs: every problem reported at once with its location, did-you-mean for typos, examples valid."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
from scene_builders import column_collapse_3d, mixed, problems

from gns_framework.assembly.ground_truth import build_ground_truth_simulator
from gns_framework.errors import RecipeError
from gns_framework.ground_truth.scene_spec import load_scene, parse_scene

SCENES = sorted((Path(__file__).resolve().parents[2] / "scenes").rglob("*.yaml"))


def test_example_scenes_exist():
    expected = {
        "sand_collapse_2d",
        "water_dam_break_2d",
        "sand_collapse_3d",
        "multi_material_2d",
        "sand_ramps_2d",
        "water_ramps_2d",
        "sand_ramps_3d",
    }
    assert {p.stem for p in SCENES} >= expected


@pytest.mark.parametrize("path", SCENES, ids=lambda p: p.stem)
def test_example_scene_is_valid_and_runnable(path, sim_registry):
    scene = load_scene(path)
    assert build_ground_truth_simulator(scene, sim_registry, path).check(scene) == []


def test_structural_problems_are_reported_together_with_locations():
    raw = mixed()
    raw["domain"]["wal_friction"] = 0.3
    raw["blocks"][0]["sise"] = [0.1, 0.1]
    raw["blocks"][1]["size"] = [0.1, "wide"]
    raw["blocks"][2]["position"] = [0.1, {"range": [0.3, 0.2]}]
    raw["time"]["frames"] = 1
    found = problems(raw)
    assert "unknown key (did you mean 'wall_friction'?)" in found["domain.wal_friction"]
    assert "did you mean 'size'" in found["blocks[0].sise"]
    assert "expected a number, {range: [low, high]} or {span: [low, high]}" in found["blocks[1].size[1]"]
    assert "low <= high" in found["blocks[2].position[1]"]
    assert "time.frames" in found
    assert len(found) == 5


def test_consistency_problems_are_reported_together():
    raw = mixed()
    raw["blocks"][0]["position"] = [0.0, 0.0, 0.0]
    raw["blocks"][1]["position"] = [0.45, 0.1]
    raw["blocks"][2]["velocity"] = [{"range": [0, 1], "per": "particle"}, 0.0]
    raw["obstacles"][0]["velocity"] = [5.0, 0.0]
    found = problems(raw)
    assert found["blocks[0].position"] == "expected 2 values (dim = 2), got 3"
    assert "outside the domain [0, 0.5]" in found["blocks[1].position[0]"]
    assert "per: particle applies to properties only" in found["blocks[2].velocity[0]"]
    assert "outside the domain" in found["obstacles[0].position[0]"]


def test_simulator_problems_name_materials_properties_and_parameters(sim_registry):
    raw = mixed()
    raw["blocks"][0]["material"] = "watr"
    raw["blocks"][1]["properties"] = {"viscosity": 1.0}
    raw["blocks"][2]["parameters"] = {"yield_stres": 10.0}
    raw["obstacles"][0]["material"] = "sand"
    found = problems(raw, sim_registry)
    assert "unknown material 'watr'" in found["blocks[0].material"]
    assert found["blocks[1].properties.viscosity"] == "material 'sand' has no property 'viscosity' (it has: friction)"
    assert "no parameter 'yield_stres'" in found["blocks[2].parameters.yield_stres"]
    assert "is not kinematic" in found["obstacles[0].material"]


def test_parameter_ranges_are_checked_at_their_extremes(sim_registry):
    raw = mixed()
    raw["blocks"][2]["parameters"] = {"poisson_ratio": {"range": [0.2, 0.6]}}
    found = problems(raw, sim_registry)
    assert "less than 0.5" in found["blocks[2].poisson_ratio"]


def test_too_few_substeps_for_the_wave_speed_says_how_many(sim_registry):
    raw = mixed()
    raw["time"]["substeps"] = 1
    message = problems(raw, sim_registry)["time.substeps"]
    assert "exceeds the stable" in message and "wave speed" in message and "use at least" in message
    needed = int(message.rsplit("use at least ", 1)[1].split()[0])
    raw["time"]["substeps"] = needed
    scene = parse_scene(raw)
    assert build_ground_truth_simulator(scene, sim_registry).check(scene) == []


def test_unknown_simulator_and_bad_simulator_params(sim_registry):
    raw = copy.deepcopy(mixed())
    raw["simulator"] = {"name": "mls_mmp"}
    assert "did you mean 'mls_mpm'" in problems(raw, sim_registry)["simulator.name"]
    raw["simulator"] = {"name": "mls_mpm", "cfl": 3}
    assert "simulator.cfl" in problems(raw, sim_registry)


def test_a_bool_is_not_a_number():
    raw = mixed()
    raw["blocks"][0]["size"] = [True, 0.1]
    assert "blocks[0].size[0]" in problems(raw)


def test_duplicate_yaml_keys_are_errors(tmp_path):
    (tmp_path / "scene.yaml").write_text("dim: 2\ndim: 3\n")
    with pytest.raises(RecipeError, match="duplicate key 'dim'"):
        load_scene(tmp_path / "scene.yaml")


def test_wall_conditions_default_to_wall_friction_on_every_face():
    raw = mixed()
    raw["domain"]["wall_friction"] = 0.4
    assert parse_scene(raw).domain.wall_conditions() == [(0.4, False)] * 4
    raw["domain"]["walls"] = {"y_min": 0.8, "x_min": "slip", "x_max": "no_slip"}
    assert parse_scene(raw).domain.wall_conditions() == [(0.0, False), (0.0, True), (0.8, False), (0.4, False)]


def test_bad_wall_conditions_are_reported_with_their_face():
    raw = mixed()
    raw["domain"]["walls"] = {"x_mn": "slip", "y_min": "sticky", "y_max": -0.1}
    found = problems(raw)
    assert "did you mean 'x_min'" in found["domain.walls.x_mn"]
    assert "'slip' or 'no_slip'" in found["domain.walls.y_min"]
    assert "friction coefficient >= 0" in found["domain.walls.y_max"]
    raw["domain"]["walls"] = {"z_min": 0.2}
    assert "faces x_min, x_max, y_min, y_max only" in problems(raw)["domain.walls.z_min"]


def test_shaped_obstacles_are_checked_for_what_their_shape_needs():
    raw = mixed()
    raw["obstacles"] = [
        {"material": "rigid", "shape": "plane", "position": [0.1, 0.1], "size": [0.1, 0.1], "angle": 95},
        {"material": "rigid", "shape": "polygon", "position": [0.1, 0.1], "vertices": [[0, 0], [0.1, 0]]},
        {
            "material": "rigid",
            "shape": "box",
            "position": [0.1, 0.1],
            "size": [0.1, 0.1],
            "angle": 10,
            "velocity": [0.1, 0.0],
        },
        {"material": "rigid", "shape": "ellipsoid", "position": [0.1, 0.1]},
        {"material": "rigid", "shape": "box", "position": [0.1, 0.1], "size": [0.1, 0.1], "vertices": [[0, 0]]},
    ]
    found = problems(raw)
    assert found["obstacles[0].size"] == "a plane takes no size"
    assert "(-90, 90) degrees" in found["obstacles[0].angle"]
    assert "at least 3 vertices" in found["obstacles[1].vertices"]
    assert "static: velocity must be 0" in found["obstacles[2].velocity"]
    assert "needs size" in found["obstacles[3].size"]
    assert "only polygons take vertices" in found["obstacles[4].vertices"]


def test_polygons_are_2d_and_rotated_blocks_must_stay_in_the_domain():
    raw = copy.deepcopy(mixed())
    raw["blocks"][1]["angle"] = {"range": [0, 90]}
    raw["blocks"][1]["size"] = [0.2, 0.02]
    raw["blocks"][1]["position"] = [0.2, 0.1]  # the 0.2 m slab stands up to 0.21 + 0.1 m: inside
    assert parse_scene(raw)
    raw["blocks"][1]["position"] = [0.2, 0.01]  # turned 90 degrees it reaches below the floor
    assert "outside the domain" in problems(raw)["blocks[1].position[1]"]
    raw = {
        **column_collapse_3d(),
        "obstacles": [
            {"material": "rigid", "shape": "polygon", "position": [0.1, 0.1, 0.1], "vertices": [[0, 0], [1, 0], [0, 1]]}
        ],
    }
    assert "polygons are 2D" in problems(raw)["obstacles[0].shape"]


def test_a_drawn_choice_of_angles_is_checked_at_each_choice():
    # A one_of angle on a plane (and on a turned block) was read as a range and crashed validation.
    raw = mixed()
    raw["obstacles"] = [{"material": "rigid", "shape": "plane", "position": [0.1, 0.1], "angle": {"one_of": [10, 95]}}]
    assert "(-90, 90) degrees" in problems(raw)["obstacles[0].angle"]
    fine = mixed()
    fine["obstacles"] = [{"material": "rigid", "shape": "plane", "position": [0.1, 0.1], "angle": {"one_of": [5, 20]}}]
    parse_scene(fine)
    turned = mixed()
    turned["blocks"][0]["angle"] = {"one_of": [0, 30]}
    # Turned by 30 degrees, the block's corners leave the domain: found, not a crash.
    assert "outside the domain" in problems(turned)["blocks[0].position[0]"]
