"""Drawing a scene: lattices fill their shapes, draws are reproducible, Warp stays unimported until a run."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scene_builders import mixed

from gns_framework.ground_truth.sampling import fill, sample_scene
from gns_framework.ground_truth.scene_spec import parse_scene


@given(
    shape=st.sampled_from(["box", "ellipsoid"]),
    lower=st.lists(st.floats(-1, 1), min_size=2, max_size=3),
    size=st.lists(st.floats(0.05, 0.5), min_size=3, max_size=3),
    spacing=st.floats(0.01, 0.05),
)
@settings(max_examples=40, deadline=None)
def test_lattice_points_lie_inside_their_shape(shape, lower, size, spacing):
    lower = np.array(lower)
    size = np.array(size[: len(lower)])
    points = fill(shape, lower, size, spacing)
    assert len(points) >= 1 or shape == "ellipsoid"
    counts = np.maximum(1, np.round(size / spacing))
    assert (points >= lower - 1e-12).all()
    assert (points <= lower + counts * spacing + 1e-12).all()
    if shape == "ellipsoid" and len(points):
        centre, radii = lower + size / 2, size / 2
        assert (((points - centre) / radii) ** 2).sum(1).max() <= 1 + 1e-9


def test_box_of_whole_cells_holds_one_particle_per_spacing_volume():
    points = fill("box", np.zeros(2), np.array([0.2, 0.4]), 0.00625)
    assert len(points) == 32 * 64
    np.testing.assert_allclose(points.min(0), [0.003125, 0.003125])


def test_same_seed_same_draw_and_another_seed_another():
    scene = parse_scene(mixed())
    a, b, c = sample_scene(scene, 1), sample_scene(scene, 1), sample_scene(scene, 2)
    for x, y in zip(a.bodies, b.bodies, strict=True):
        assert x.position.tobytes() == y.position.tobytes()
        assert x.values.keys() == y.values.keys()
    assert any(
        x.position.shape != z.position.shape or not np.array_equal(x.position, z.position)
        for x, z in zip(a.bodies, c.bodies, strict=True)
    )


def test_per_particle_properties_vary_and_per_trajectory_ones_do_not():
    raw = mixed()
    raw["blocks"][0]["parameters"] = {"bulk_modulus": {"range": [1e5, 2e5]}}
    sample = sample_scene(parse_scene(raw), 0)
    assert np.unique(sample.blocks[1].values["friction"]).size == sample.blocks[1].num_particles
    assert np.unique(sample.blocks[0].values["bulk_modulus"]).size == 1


def test_importing_and_listing_components_does_not_import_warp():
    code = (
        "import sys\n"
        "from gns_framework.plugins import load_registry\n"
        "from gns_framework.cli import build_parser\n"
        "registry = load_registry()\n"
        "assert 'mls_mpm' in registry.names('simulator')\n"
        "build_parser(['generate', 'convert'])\n"
        "assert 'warp' not in sys.modules, 'warp was imported'\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def _with_obstacle(obstacle: dict) -> dict:
    raw = mixed()
    raw["obstacles"] = [{"material": "rigid", **obstacle}]
    return raw


def test_rotated_box_particles_keep_their_count_and_spacing_about_the_centre():
    flat = sample_scene(parse_scene(_with_obstacle({"position": [0.1, 0.2], "size": [0.25, 0.0625]})), 0).obstacles[0]
    turned = sample_scene(
        parse_scene(_with_obstacle({"position": [0.1, 0.2], "size": [0.25, 0.0625], "angle": 90.0})), 0
    ).obstacles[0]
    assert turned.num_particles == flat.num_particles
    np.testing.assert_allclose(turned.position.mean(0), flat.position.mean(0), atol=1e-12)
    # Turned by 90 degrees the long side stands along y.
    np.testing.assert_allclose(np.ptp(turned.position, axis=0), np.ptp(flat.position, axis=0)[::-1], atol=1e-12)


def test_plane_is_recorded_as_rows_under_its_surface_inside_the_domain():
    raw = _with_obstacle({"shape": "plane", "position": [0.25, 0.1], "angle": 20.0})
    scene = parse_scene(raw)
    plane = sample_scene(scene, 0).obstacles[0]
    slope = np.tan(np.radians(20.0))
    below = 0.1 + slope * (plane.position[:, 0] - 0.25) - plane.position[:, 1]  # vertical depth under the surface
    depth = below * np.cos(np.radians(20.0))
    assert (depth > 0).all() and depth.max() < scene.domain.cell_size
    assert np.unique(np.round(depth / scene.particle_spacing - 0.5, 6)).size == scene.particles_per_cell
    assert (plane.position >= 0).all() and (plane.position <= 0.5).all()
    # The rows span the domain: first and last particles near the side walls.
    assert plane.position[:, 0].min() < 2 * scene.particle_spacing
    assert plane.position[:, 0].max() > 0.5 - 2 * scene.particle_spacing


def test_polygon_particles_fill_it_and_its_vertices_turn_counter_clockwise():
    clockwise = [[0, 0], [0, 0.2], [0.2, 0.2], [0.2, 0]]
    obstacle = sample_scene(
        parse_scene(_with_obstacle({"shape": "polygon", "position": [0.1, 0.1], "vertices": clockwise})), 0
    ).obstacles[0]
    x, y = obstacle.vertices[:, 0], obstacle.vertices[:, 1]
    assert np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) > 0
    spacing = parse_scene(mixed()).particle_spacing
    assert obstacle.num_particles == round(0.2 / spacing) ** 2
    assert (obstacle.position > 0.1).all() and (obstacle.position < 0.3).all()


def _general_scene(grid: int = 96):
    from gns_framework.config.yaml_files import load_yaml_mapping

    raw = load_yaml_mapping("scenes/sand_general_2d.yaml")
    raw["domain"]["grid"] = grid
    return parse_scene(raw)


def _layout(sample):
    """What a scene is, apart from its particles: box, walls, and each body's place, size and properties."""
    return (
        np.round(sample.bounds, 6).tolist(),
        sample.walls.tolist(),
        [
            (
                b.location,
                np.round(b.lower, 9).tolist(),
                np.round(b.size, 9).tolist(),
                b.friction,
                {k: round(float(v.mean()), 9) for k, v in b.values.items()},
            )
            for b in sample.bodies
        ],
    )


def test_a_drawn_scene_at_another_grid_is_the_same_scene_refilled(tmp_path):
    """Issue 46: the half-grid yardstick runs the scene the data holds. Drawn again at grid 48 the general scene is
    another scene (columns, frictions and box elsewhere); at_resolution keeps every body and the box (to half a
    coarse cell) and refills it at the coarse spacing."""
    from gns_framework.ground_truth.sampling import at_resolution

    scene, coarse = _general_scene(96), _general_scene(48)
    differs = 0
    for seed in range(8):
        data = sample_scene(scene, seed)
        redrawn = sample_scene(coarse, seed)
        differs += _layout(redrawn)[2] != _layout(data)[2]
        same = at_resolution(data, scene, coarse, seed)
        assert same.scene.particle_spacing == coarse.particle_spacing == 2 * scene.particle_spacing
        kept, now = _layout(data), _layout(same)
        assert now[1:] == kept[1:], "walls and every body as drawn"
        # Bounds are stored in float32: half a coarse cell, to float32 rounding of ~1 m.
        assert np.abs(np.array(now[0]) - np.array(kept[0])).max() <= coarse.domain.cell_size / 2 + 1e-6
        for before, after in zip(data.blocks, same.blocks, strict=True):
            # A quarter of the particles (twice the spacing in 2D), filling the same box.
            assert abs(after.num_particles - before.num_particles / 4) <= before.num_particles / 8 + 4
            assert (after.position >= before.lower - coarse.particle_spacing).all()
            assert (after.position <= before.lower + before.size + coarse.particle_spacing).all()
    assert differs >= 6, "drawing anew at another grid gives other scenes: the test would not see the bug"


def test_at_the_data_s_own_grid_the_bodies_and_box_are_the_data_s():
    from gns_framework.ground_truth.sampling import at_resolution

    scene = _general_scene(96)
    data = sample_scene(scene, 3)
    same = at_resolution(data, scene, scene, 3)
    assert _layout(same) == _layout(data)
    for before, after in zip(data.blocks, same.blocks, strict=True):
        assert after.num_particles == before.num_particles  # the jitter alone is drawn anew


def test_an_obstacle_that_records_its_friction_gives_it_to_its_particles_and_draws_nothing_more():
    raw = mixed()
    raw["obstacles"][0]["friction"] = {"range": [0.3, 0.5]}
    recording = {**raw, "obstacles": [{**raw["obstacles"][0], "record_friction": True}]}
    plain, recorded = sample_scene(parse_scene(raw), 3), sample_scene(parse_scene(recording), 3)
    for x, y in zip(plain.bodies, recorded.bodies, strict=True):  # the same draws, particle for particle
        assert x.position.tobytes() == y.position.tobytes() and x.friction == y.friction
    from gns_framework.plugins import load_registry

    registry = load_registry()
    materials = {name: registry.get("material", name) for name in registry.names("material")}
    obstacle = recorded.obstacles[0]
    assert 0.3 <= obstacle.friction <= 0.5
    column = recorded.property_names.index("friction")
    assert recorded.property_names == plain.property_names == ("friction",)
    rows = recorded.material_property(materials)[:, column]
    kinematic = slice(recorded.num_particles - obstacle.num_particles, None)
    np.testing.assert_array_equal(rows[kinematic], np.float32(obstacle.friction))
    np.testing.assert_array_equal(
        rows[: kinematic.start], plain.material_property(materials)[: kinematic.start, column]
    )
    assert (plain.material_property(materials)[kinematic, column] == 0).all()  # unrecorded: the material's default


def test_a_scene_whose_only_friction_is_an_obstacle_s_records_that_column():
    raw = mixed()
    raw["blocks"][1].pop("properties")
    assert parse_scene(raw).property_names == ()
    raw["obstacles"][0]["record_friction"] = True
    assert parse_scene(raw).property_names == ("friction",)
