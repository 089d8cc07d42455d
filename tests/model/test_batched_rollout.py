"""Batched rollouts: each scene's frames as when rolled out alone, its own walls, its own guard reports."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from gns_framework.data.trajectory import Trajectory
from gns_framework.model.batched_rollout import rollout_batch
from gns_framework.model.rollout import rollout
from gns_framework.model.rollout_guard import RolloutGuard
from gns_framework.plugins import load_registry
from gns_framework.stability.extreme import TYPES, tiny_simulator

pytestmark = pytest.mark.usefixtures("one_torch_thread")
REGISTRY = load_registry()


def _scene(seed: int, particles: int, frames: int = 12) -> Trajectory:
    """A falling cloud of the extreme scene's types (kinematic ones included), ``frames`` frames."""
    rng = np.random.default_rng(seed)
    start = rng.uniform(0.3, 0.7, (particles, 2))
    velocity = rng.normal(0, 0.003, (particles, 2))
    position = np.stack([start + t * velocity for t in range(frames)]).astype(np.float32)
    types = np.array([TYPES[i % len(TYPES)] for i in range(particles)], dtype=np.int64)
    return Trajectory(position, types, key=f"scene_{seed}")


def test_each_scene_of_a_batch_is_rolled_out_as_alone():
    simulator = tiny_simulator(REGISTRY, 2)
    scenes = [_scene(0, 30), _scene(1, 45), _scene(2, 20, frames=14)]
    batched = rollout_batch(simulator, scenes)
    assert [r.num_steps for r in batched] == [6, 6, 6]  # as far as the shortest goes
    for scene, result in zip(scenes, batched, strict=True):
        alone = rollout(simulator, scene, steps=6)
        assert result.key == scene.key and result.predicted.shape == alone.predicted.shape
        # Only the matrix products see other rows: float32 rounding of the model's outputs over 6 steps.
        scale = np.abs(alone.predicted).max()
        np.testing.assert_allclose(result.predicted, alone.predicted, rtol=0, atol=1e-5 * scale)
        np.testing.assert_array_equal(result.predicted_particles, alone.predicted_particles)
    kinematic = ~batched[0].predicted_particles
    assert kinematic.any()
    np.testing.assert_array_equal(batched[0].predicted[:, kinematic], scenes[0].position[6:12][:, kinematic])


def test_a_batch_guards_each_scene_by_its_own_walls_and_reports_its_own_particles():
    simulator = tiny_simulator(REGISTRY, 2)
    inside = _scene(0, 30)
    small_box = replace(_scene(1, 30), bounds=np.array([[0.0, 0.5], [0.0, 1.0]], np.float32))
    guard = RolloutGuard(simulator.setup, margin=0.0, on_violation="clamp")
    first, second = rollout_batch(simulator, [inside, small_box], steps=3, guard=guard)
    assert first.guard_violations == ()
    assert second.guard_violations
    escaped = np.unique(np.concatenate([v.particles for v in second.guard_violations]))
    assert escaped.max() < 30 and set(escaped) <= set(np.flatnonzero(small_box.position[5, :, 0] > 0.45))
    assert (second.predicted[..., 0] <= 0.5 + 1e-6).all()


def test_an_empty_batch_and_too_short_scenes():
    simulator = tiny_simulator(REGISTRY, 2)
    assert rollout_batch(simulator, []) == []
    with pytest.raises(ValueError, match="shortest trajectory has 5 frames"):
        rollout_batch(simulator, [_scene(0, 10), _scene(1, 10, frames=5)])


def test_evaluate_batches_scenes_of_one_length_and_keeps_a_diverged_scene_to_itself():
    from gns_framework.evaluation.candidates import learned_positions, learned_positions_batch

    simulator = tiny_simulator(REGISTRY, 2)
    scenes = [_scene(0, 30), _scene(1, 25, frames=14), _scene(2, 20)]
    batched = learned_positions_batch(simulator, scenes, "cpu")
    for scene, positions in zip(scenes, batched, strict=True):
        alone = learned_positions(simulator, scene, "cpu")
        assert positions.shape == alone.shape == (scene.num_steps - 6, scene.num_particles, 2)
        np.testing.assert_allclose(positions, alone, rtol=0, atol=1e-5 * np.abs(alone).max())
    # A NaN input makes its own scene diverge (the guard stops); the others are still rolled out.
    broken = _scene(3, 30)
    broken.position[:, 0] = np.nan
    good, bad = learned_positions_batch(simulator, [scenes[0], broken], "cpu")
    assert np.isfinite(good).all() and np.isnan(bad).all()
