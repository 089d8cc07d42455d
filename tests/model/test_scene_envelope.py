"""A scene file against a model's training, field by field, before any data is made (issue 46, item 6): the
shipped general sand model and scenes a user would write."""

from __future__ import annotations

import copy

import pytest

from gns_framework.assembly.trained import load_trained
from gns_framework.ground_truth.scene_spec import SceneSpec, parse_scene
from gns_framework.model.scene_envelope import scene_file_terms, scene_problems, value_range
from gns_framework.plugins import load_registry

BASE = {
    "name": "mine",
    "dim": 2,
    "domain": {"bounds": [[0.0, 2.0], [0.0, 1.0]], "grid": 96, "wall_friction": 0.5},
    "time": {"frame_dt": 0.005, "substeps": 40, "frames": 240},
    "particles_per_cell": 2,
    "blocks": [{"material": "sand", "position": [0.0, 0.0], "size": [0.2, 0.4], "properties": {"friction": 0.7}}],
}


@pytest.fixture(scope="module")
def general():
    model = load_trained("models/sand2d_general.pt", load_registry())
    return model.envelope, SceneSpec.model_validate(model.metadata.generated_from["scene"])


def _scene(**changes) -> SceneSpec:
    raw = copy.deepcopy(BASE)
    for path, value in changes.items():
        *parents, last = path.split("__")
        target = raw
        for key in parents:
            target = target[int(key)] if key.isdigit() else target[key]
        target[last] = value
    return parse_scene(raw, "mine.yaml")


def test_a_column_inside_everything_trained_passes_and_a_rough_top_it_never_reaches_is_no_reason(general):
    envelope, trained = general
    assert scene_problems(_scene(), envelope, trained) == []  # its top face is rough (wall_friction), trained slip


@pytest.mark.parametrize(
    ("changes", "field", "says"),
    [
        ({"blocks__0__size": [0.2, 0.7]}, "blocks[0].size[1]", "0.7 m along y; trained sand blocks 0.1 .. 0.5 m"),
        ({"domain__grid": 72}, "domain.grid", "the model was trained at 0.01042 m: domain.grid 96"),
        ({"time__frame_dt": 0.01}, "time.frame_dt", "the model steps 0.01 s: frame_dt 0.005 s"),
        ({"domain__bounds": [[0.0, 3.0], [0.0, 1.0]], "domain__grid": 144}, "domain.bounds[0]", "trained 0.75 .. 2 m"),
        ({"blocks__0__properties": {"friction": 0.3}}, "blocks[0].properties.friction", "0.3; trained 0.5001"),
        ({"domain__walls": {"x_min": "no_slip"}}, "domain.walls.x_min", "no-slip; trained slip or friction"),
        ({"blocks__0__velocity": [0.0, 2.0]}, "domain.walls.y_max", "friction 0.5; trained slip"),
    ],
)
def test_each_field_outside_is_named_with_what_was_trained(general, changes, field, says):
    envelope, trained = general
    problems = scene_problems(_scene(**changes), envelope, trained)
    assert [f for f, _ in problems] == [field], problems
    assert says in problems[0][1], problems


def test_the_training_scene_and_the_canonical_scenes_are_inside(general):
    from pathlib import Path

    from gns_framework.ground_truth.scene_spec import load_scene

    envelope, trained = general
    assert scene_problems(trained, envelope, trained) == []
    for path in sorted(Path("scenes/canonical").glob("*.yaml")):
        assert scene_problems(load_scene(path), envelope, trained) == [], path


def test_the_envelope_in_scene_file_terms_names_the_grid_and_the_measured_distance_apart(general):
    envelope, trained = general
    text = "\n".join(scene_file_terms(trained, envelope))
    assert (
        "domain.grid 96 over the largest box (2 m, dx 0.02083 m), particles_per_cell 2: particles 0.01042 m apart"
        in text
    )
    assert "median nearest-neighbour distance 0.008819 m" in text  # another quantity, under its own name
    assert "blocks[0]: 1 .. 3 sand box(s) of 0.1 .. 0.4 x 0.1 .. 0.5 m, friction 0.5 .. 0.9" in text


def test_value_ranges_of_every_kind_of_scene_value():
    scene = parse_scene(
        {
            **BASE,
            "blocks": [
                {**BASE["blocks"][0], "size": [{"range": [0.1, 0.3]}, {"one_of": [0.2, {"range": [0.4, 0.5]}]}]}
            ],
        },
        "x",
    )
    assert [value_range(v) for v in scene.blocks[0].size] == [(0.1, 0.3), (0.2, 0.5)]
    assert (
        value_range(
            parse_scene({**BASE, "blocks": [{**BASE["blocks"][0], "position": [{"span": [0, 1]}, 0.0]}]}, "x")
            .blocks[0]
            .position[0]
        )
        is None
    )


def test_an_obstacle_s_friction_is_judged_where_the_model_saw_it_recorded(general):
    """A model whose obstacles recorded their friction (0.3 .. 0.5) refuses an obstacle that does not record it (its
    particles would read 0) or whose friction lies outside; a checkpoint from before it judges neither."""
    from dataclasses import replace

    envelope, trained = general
    seeing = replace(envelope, fixed_properties={"friction": [0.3, 0.5]})
    hump = {"material": "rigid", "shape": "box", "position": [1.0, 0.0], "size": [0.1, 0.1]}
    recorded = {**hump, "friction": {"range": [0.35, 0.45]}, "record_friction": True}
    assert scene_problems(_scene(obstacles=[recorded]), seeing, trained) == []
    (unrecorded,) = scene_problems(_scene(obstacles=[{**recorded, "record_friction": False}]), seeing, trained)
    assert unrecorded == (
        "obstacles[0].friction",
        "0 (not recorded: its particles read 0; record_friction: true); trained 0.3 .. 0.5",
    )
    (rough,) = scene_problems(_scene(obstacles=[{**recorded, "friction": 0.8}]), seeing, trained)
    assert rough == ("obstacles[0].friction", "0.8; trained 0.3 .. 0.5")
    assert envelope.fixed_properties == {"friction": [0.0, 0.0]}  # the shipped model never saw it recorded
    (blind,) = scene_problems(_scene(obstacles=[recorded]), envelope, trained)
    assert blind == ("obstacles[0].friction", "0.35 .. 0.45; trained 0 .. 0")
    assert scene_problems(_scene(obstacles=[hump]), envelope, trained) == []
    older = replace(envelope, fixed_properties=None)  # a checkpoint from before fixed particles were measured
    assert scene_problems(_scene(obstacles=[{**recorded, "friction": 0.8}]), older, trained) == []
    text = "\n".join(scene_file_terms(parse_scene({**BASE, "obstacles": [recorded]}), seeing))
    assert "obstacles[0]: 1 rigid box(s) of 0.1 x 0.1 m, friction 0.35 .. 0.45 (recorded)" in text
    assert "property friction of fixed particles: 0.3 .. 0.5" in text
