"""The simulator candidates of ``gns evaluate`` re-simulate each test case with that case's own seed."""

from __future__ import annotations

import numpy as np
import torch
import yaml

from gns_framework.assembly.data import open_dataset
from gns_framework.assembly.ground_truth import build_ground_truth_simulator
from gns_framework.config.recipe import DatasetSpec
from gns_framework.evaluation.candidates import cases_from_split, simulator_candidates
from gns_framework.ground_truth.generate import generate_dataset
from gns_framework.ground_truth.scene_spec import parse_scene
from gns_framework.plugins import load_registry

SCENE = """
name: tiny_collapse
dim: 2
domain: {bounds: [[0.0, 1.0], [0.0, 0.5]], grid: 16}
time: {frame_dt: 0.005, substeps: 10, frames: 10}
seed: 2
blocks:
  - material: sand
    position: [0.0, 0.0]
    size: [0.2, {range: [0.2, 0.3]}]
    properties: {friction: {range: [0.6, 0.8]}}
"""


def _generated(text: str, folder, tests: int):
    """(registry, scene, simulator, dataset, test cases) of the scene ``text`` generated into ``folder``."""
    registry = load_registry()
    scene = parse_scene(yaml.safe_load(text), "scene")
    simulator = build_ground_truth_simulator(scene, registry, "scene")
    counts = {"train": 1, "valid": 0, "test": tests}
    generate_dataset(scene, simulator, folder, registry.get("dataset", "safe"), counts, progress=False)
    dataset = open_dataset(DatasetSpec(path=str(folder)), registry)
    return registry, scene, simulator, dataset, cases_from_split(dataset.split("test"))


def test_the_reference_setting_reproduces_every_case_whatever_the_key_order(tmp_path):
    registry, _, _, dataset, cases = _generated(SCENE, tmp_path, 3)
    # The seed-named keys of this scene do not sort in generation order: a test of file order, not luck.
    assert [c.key for c in cases] != sorted(c.key for c in cases)
    (reference,) = simulator_candidates(dataset.metadata(), registry, cases, 3, [1.0], [1.0])
    for case in cases:
        np.testing.assert_array_equal(reference.simulate(case).position, case.position[3:])


def test_a_bfloat16_row_is_named_so_and_rolls_out_with_bfloat16_products(registry):
    """Each precision is a row of its own; its positions are the float32 rollout's up to bfloat16's rounding."""
    from inverse_cases import MODEL, SAND
    from synthetic import soft_sphere_trajectory

    from gns_framework.assembly.trained import load_trained
    from gns_framework.evaluation.candidates import learned_candidate

    model = load_trained(MODEL, registry)
    trajectory = soft_sphere_trajectory(3, frames=14, block=5, particle_types=(SAND,), with_property=True, key="k")
    device = torch.device("cpu")
    float32 = learned_candidate(model, "m", device)
    bfloat16 = learned_candidate(model, "m", device, 1, "bfloat16")
    assert (float32.name, bfloat16.name) == ("m", "m [bfloat16]")
    assert learned_candidate(model, "m", device, 2, "bfloat16").name == "m [bfloat16, batch 2]"
    assert "products in bfloat16" in bfloat16.settings
    exact, rounded = float32.simulate(trajectory).position, bfloat16.simulate(trajectory).position
    moved = np.abs(exact - trajectory.position[model.simulator.setup.history - 1]).max()
    difference = np.abs(rounded - exact).max()
    # bfloat16 keeps 8 bits of mantissa (relative rounding 2^-9 = 2e-3 per product): over a few steps the
    # positions differ by a small share of how far the particles moved, never by nothing.
    assert 0 < difference < 0.05 * moved, (difference, moved)


def test_evaluate_rolls_out_as_gns_rollout_does_walls_holding_and_counting_the_particles_held(registry):
    """One boundary treatment (issue 46): a learned row uses the model's rollout.guard, as ``gns rollout`` does, so
    no particle ends beyond a wall's margin, the two commands report the same positions, and each case counts the
    particles a wall held."""
    import dataclasses

    from inverse_cases import MODEL, SAND
    from synthetic import soft_sphere_trajectory

    from gns_framework.assembly.trained import load_trained
    from gns_framework.evaluation.candidates import learned_candidate
    from gns_framework.model.rollout import rollout
    from gns_framework.model.rollout_guard import RolloutGuard

    model = load_trained(MODEL, registry)
    guard_spec = model.recipe.rollout.guard.model_copy(update={"margin": 0.0, "on_violation": "clamp"})
    recipe = model.recipe.model_copy(update={"rollout": model.recipe.rollout.model_copy(update={"guard": guard_spec})})
    model = dataclasses.replace(model, recipe=recipe)
    trajectory = soft_sphere_trajectory(3, frames=14, block=5, particle_types=(SAND,), with_property=True, key="k")
    # Walls just inside the cloud's first frame: every step some particles pass one and are put back.
    first = trajectory.position[model.simulator.setup.history - 1]
    box = np.stack([first.min(0) + 0.01, first.max(0) - 0.01], axis=1).astype(np.float32)
    trajectory = dataclasses.replace(trajectory, bounds=box)

    prediction = learned_candidate(model, "m", torch.device("cpu")).simulate(trajectory)
    guard = RolloutGuard.from_spec(model.simulator.setup, guard_spec)
    same = rollout(model.simulator, trajectory, guard=guard)
    np.testing.assert_array_equal(prediction.position, same.predicted)
    held = {int(i) for v in same.guard_violations if v.escaped for i in v.particles}
    assert prediction.held == len(held) > 0
    assert (prediction.position >= box[:, 0] - 1e-6).all() and (prediction.position <= box[:, 1] + 1e-6).all()
    batched = learned_candidate(model, "m", torch.device("cpu"), batch=2).simulate_batch([trajectory, trajectory])
    assert [p.held for p in batched] == [prediction.held] * 2


DRAWN = """
name: drawn_collapses
dim: 2
domain:
  bounds: [[0.0, 1.0], [0.0, 0.5]]
  grid: 32
  extent: [{range: [0.6, 1.0]}, 0.5]
  walls: {x_max: {one_of: [slip, {range: [0.3, 0.6]}]}}
time: {frame_dt: 0.005, substeps: 10, frames: 8}
seed: 4
jitter: 0.2
no_overlap: true
blocks:
  - material: sand
    count: 2
    position: [{span: [0, 1]}, 0.0]
    size: [{range: [0.1, 0.2]}, {range: [0.1, 0.2]}]
    properties: {friction: {range: [0.5, 0.9]}}
"""


def test_a_reduced_grid_row_simulates_the_scene_the_data_holds(tmp_path):
    """Issue 46: the half-grid MPM row starts from the data's drawn scene (its box, columns and walls), refilled at
    the coarse spacing: its first frame covers the same columns to a coarse spacing; drawn anew, it would not."""
    registry, scene, simulator, dataset, cases = _generated(DRAWN, tmp_path, 4)
    (half,) = simulator_candidates(dataset.metadata(), registry, cases, 3, [0.5], [1.0])
    assert "drawn anew" not in half.settings
    coarse = 2 * scene.particle_spacing

    def same_columns(first: np.ndarray, case) -> bool:
        """The leftmost and rightmost sand and the highest, within two coarse spacings of the data's."""
        data = case.position[2]
        ends = np.abs(np.sort(first[:, 0])[[0, -1]] - np.sort(data[:, 0])[[0, -1]]).max()
        return bool(ends < 2 * coarse and abs(first[:, 1].max() - data[:, 1].max()) < 2 * coarse)

    coarse_scene = scene.model_copy(update={"domain": scene.domain.model_copy(update={"grid": 16})})
    drawn_anew = 0
    for case in cases:
        assert same_columns(np.asarray(half.simulate(case).start), case), case.key
        redrawn = simulator.simulate(coarse_scene, int(case.key.split("_")[1]))
        drawn_anew += not same_columns(redrawn.position[2], case) or not np.allclose(redrawn.bounds, case.bounds)
    assert drawn_anew >= 2, "scenes drawn anew at the coarse grid differ: the check above would see the bug"


def test_a_fresh_jitter_row_runs_the_data_scenes_on_another_lattice_jitter(tmp_path):
    """The simulator's own spread: at the data's grid and time step, each case's drawn scene refilled with a fresh
    jitter. Its particles start where the data's do up to the two jitters (each at most 0.2 spacings per axis), yet
    not on them: a row that reproduced the data (the reference) would measure no spread at all."""
    registry, scene, _, dataset, cases = _generated(DRAWN, tmp_path, 3)
    (fresh,) = simulator_candidates(dataset.metadata(), registry, cases, 3, [1.0], [1.0], fresh_jitter=True)
    assert not fresh.reference and "fresh lattice jitter" in fresh.settings
    both_jitters = 2 * scene.jitter * scene.particle_spacing
    for case in cases:
        start = np.asarray(fresh.simulate(case).start)
        data = case.position[2]
        assert start.shape == data.shape, case.key
        moved = np.abs(start - data).max(axis=1)
        assert moved.max() <= both_jitters * (1 + 1e-5), case.key
        assert np.median(moved) > 0.1 * both_jitters, case.key
