"""Scenes that draw their domain, face conditions, body counts and placements per trajectory."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from gns_framework.errors import GnsError, RecipeError
from gns_framework.ground_truth.sampling import sample_scene
from gns_framework.ground_truth.scene_spec import load_scene, parse_scene

GENERAL = load_scene("scenes/sand_general_2d.yaml")


def columns(**changes) -> dict:
    """A box of drawn size and walls with 1-3 spanned sand columns, kept apart."""
    raw = {
        "dim": 2,
        "domain": {
            "bounds": [[0.0, 2.0], [0.0, 1.0]],
            "grid": 96,
            "extent": [{"range": [0.75, 2.0]}, {"range": [0.5, 1.0]}],
            "walls": {"x_min": {"one_of": ["slip", {"range": [0.3, 0.6]}]}, "y_min": {"range": [0.3, 0.6]}},
        },
        "time": {"frame_dt": 0.005, "substeps": 40, "frames": 3},
        "no_overlap": True,
        "blocks": [
            {
                "material": "sand",
                "count": {"range": [1, 3]},
                "position": [{"one_of": [{"span": 0}, {"span": 1}, {"span": [0, 1]}]}, 0.0],
                "size": [{"range": [0.1, 0.4]}, {"range": [0.1, 0.5]}],
                "properties": {"friction": {"range": [0.5, 0.9]}},
            }
        ],
    }
    raw.update(changes)
    return raw


def problems(raw: dict) -> dict[str, str]:
    with pytest.raises(RecipeError) as info:
        parse_scene(raw)
    return dict(info.value.problems)


def test_drawn_domains_are_whole_cells_inside_the_bounds_and_keep_the_cell_size():
    scene = parse_scene(columns())
    dx = scene.domain.cell_size
    sizes = set()
    for seed in range(20):
        drawn = sample_scene(scene, seed).scene.domain
        assert drawn.cell_size == dx
        for (lo, hi), (low, high) in zip(drawn.bounds, [(0.75, 2.0), (0.5, 1.0)], strict=True):
            cells = (hi - lo) / dx
            assert abs(cells - round(cells)) < 1e-9
            assert low - dx / 2 <= hi - lo <= high + dx / 2
        sizes.add(tuple(hi for _, hi in drawn.bounds))
    assert len(sizes) == 20


def test_faces_draw_slip_or_friction_and_undrawn_faces_keep_wall_friction():
    scene = parse_scene(columns())
    frictions = np.array([sample_scene(scene, seed).walls[:, 0] for seed in range(40)])
    x_min, x_max, y_min = frictions[:, 0], frictions[:, 1], frictions[:, 2]
    assert (x_min == 0).any() and ((x_min >= 0.3) & (x_min <= 0.6)).any()
    assert ((x_min == 0) | ((x_min >= 0.3 - 1e-6) & (x_min <= 0.6 + 1e-6))).all()
    assert np.all(x_max == np.float32(0.5))  # the domain's wall_friction
    assert ((y_min >= 0.3 - 1e-6) & (y_min <= 0.6 + 1e-6)).all() and np.unique(y_min).size == 40


def test_counts_spans_and_no_overlap_place_every_column_inside_and_apart():
    scene = parse_scene(columns())
    counts, at_wall = set(), 0
    for seed in range(30):
        sample = sample_scene(scene, seed)
        bounds = sample.bounds
        counts.add(len(sample.blocks))
        boxes = [(b.lower, b.lower + b.size) for b in sample.blocks]
        for lower, upper in boxes:
            # bounds are float32 (as recorded), the boxes float64: 1e-6 m is far below the float32 rounding.
            assert (lower >= bounds[:, 0] - 1e-6).all() and (upper <= bounds[:, 1] + 1e-6).all()
            at_wall += bool(np.isclose(lower[0], bounds[0, 0]) or np.isclose(upper[0], bounds[0, 1]))
        for i, (lo_a, hi_a) in enumerate(boxes):
            for lo_b, hi_b in boxes[i + 1 :]:
                gap = np.maximum(lo_b - hi_a, lo_a - hi_b)
                assert gap.max() >= scene.particle_spacing - 1e-9
        friction = {float(b.values["friction"][0]) for b in sample.blocks}
        assert len(friction) == len(sample.blocks)  # each column draws its own
    assert counts == {1, 2, 3}
    assert at_wall > 0


def test_overlap_is_possible_without_no_overlap():
    raw = columns(no_overlap=False)
    raw["blocks"][0]["count"] = 3
    raw["blocks"][0]["position"] = [0.0, 0.0]
    sample = sample_scene(parse_scene(raw), 0)
    assert len(sample.blocks) == 3 and all(np.array_equal(b.lower, [0.0, 0.0]) for b in sample.blocks)


def test_unplaceable_bodies_are_an_error_naming_the_scene_and_seed():
    raw = columns()
    raw["domain"]["extent"] = [0.75, 0.5]
    raw["blocks"][0]["count"] = 3
    raw["blocks"][0]["size"] = [0.4, 0.2]
    with pytest.raises(GnsError, match=r"seed 5: no_overlap could not place"):
        sample_scene(parse_scene(raw), 5)


def test_a_fixed_scene_draws_the_same_particles_as_before_the_drawn_domain():
    """Fixed values draw nothing: the demo's particles are what its seeds always gave."""
    demo = load_scene("scenes/demo_sand_2d.yaml")
    sample = sample_scene(demo, 1234)
    rng = np.random.default_rng(1234)
    height = rng.uniform(0.2, 0.3)
    assert sample.blocks[0].size[1] == height
    assert sample.scene is demo and sample.bounds.tolist() == [[0.0, 1.0], [0.0, 0.5]]


def test_obstacle_polygon_is_placed_by_its_corners_box():
    sample = next(
        s for s in (sample_scene(GENERAL, seed) for seed in range(40)) if any(o.shape == "polygon" for o in s.obstacles)
    )
    hump = next(o for o in sample.obstacles if o.shape == "polygon")
    width = sample.bounds[0, 1] - sample.bounds[0, 0]
    assert hump.vertices[:, 1].min() == pytest.approx(0.0)
    assert 0.15 * (width - 0.36) - 1e-6 <= hump.vertices[:, 0].min() <= 0.85 * (width - 0.36) + 1e-6


@pytest.mark.parametrize(
    "change, where, message",
    [
        (lambda r: r["domain"].update(extent=[2.5, 0.5]), "domain.extent[0]", "must lie in (0, 2]"),
        (lambda r: r["domain"].update(extent=[1.0]), "domain.extent", "expected 2 values"),
        (lambda r: r["domain"].update(extent=[{"span": 0.5}, 0.5]), "domain.extent[0]", "a length in metres"),
        (
            lambda r: r["blocks"][0].update(size=[{"span": 0.5}, 0.2]),
            "blocks[0].size[0]",
            "span applies to positions only",
        ),
        (lambda r: r["blocks"][0].update(count=1.5), "blocks[0].count", "whole number"),
        (lambda r: r["blocks"][0].update(count={"range": [0, 2]}), "blocks", "at least 1"),
        (lambda r: r["blocks"][0].update(angle=10), "blocks[0].position", "takes no angle"),
        (
            lambda r: r["blocks"][0]["position"].__setitem__(0, {"span": [0.5, 1.5]}),
            "blocks[0].position[0]",
            "0 <= low",
        ),
        (
            lambda r: r["blocks"][0]["position"].__setitem__(0, {"one_of": [0.1], "weights": [1, 2]}),
            "blocks[0].position[0]",
            "one per option",
        ),
        (
            lambda r: r["domain"]["walls"].update(x_max={"one_of": ["rough"]}),
            "domain.walls.x_max",
            "friction coefficient",
        ),
        (lambda r: r["domain"]["walls"].update(x_max={"range": [0.6, 0.3]}), "domain.walls.x_max", "low <= high"),
        (lambda r: r["blocks"][0].update(size=[0.1, 0.7]), "blocks[0].position[1]", "outside the domain"),
    ],
)
def test_bad_draws_are_located(change, where, message):
    raw = copy.deepcopy(columns())
    change(raw)
    found = problems(raw)
    located = [key for key in found if key == where or key.startswith(where + ".")]
    assert located, found
    assert any(message in found[key] for key in located), found


def test_general_scene_is_valid_and_simulates_its_own_walls(sim_registry):
    from gns_framework.assembly.ground_truth import build_ground_truth_simulator

    assert build_ground_truth_simulator(GENERAL, sim_registry, "scene").check(GENERAL) == []
