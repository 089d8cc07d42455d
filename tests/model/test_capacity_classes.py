"""Capacity classes (model/capacity_classes.py): the ladder, the padded batch, and batches of different sizes that
replay one capture (emulated on the CPU), each scene's frames its own rollout's."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch
from fixed_capacity_cases import small_simulator, wandering_trajectory

from gns_framework.data.batch import window
from gns_framework.model.batched_rollout import rollout_batch
from gns_framework.model.capacity_classes import CaptureClasses, padded, particle_capacity
from gns_framework.model.rollout import rollout
from gns_framework.model.rollout_guard import RolloutGuard

PAPER = {"name": "interaction_network", "message_passing_steps": 2, "edge_block": "plain"}


def test_the_ladder_holds_every_count_at_most_a_quarter_above_it():
    assert [particle_capacity(n) for n in (1, 8, 9, 11, 15, 17, 33, 1000)] == [8, 8, 10, 12, 16, 20, 40, 1024]
    for n in range(8, 5000):
        assert n <= particle_capacity(n) <= 1.25 * n, n


def test_a_padded_batch_has_the_class_shape_with_nan_rows_in_an_example_of_their_own():
    scenes = [wandering_trajectory(particles=n, frames=8, seed=n) for n in (7, 5)]
    windows = [window(t, 0, 6, with_target=False) for t in scenes]
    batch = padded(windows, 16, scenes=3)
    assert batch.num_particles == 16 and batch.num_examples == 4  # 2 scenes, 1 empty, 1 of padding
    assert batch.batch.tolist() == [0] * 7 + [1] * 5 + [3] * 4
    assert torch.isfinite(batch.position_sequence[:12]).all() and torch.isnan(batch.position_sequence[12:]).all()
    assert batch.particle_type[12:].tolist() == [int(scenes[1].particle_type[-1])] * 4
    with pytest.raises(ValueError, match="exceed a class of 3 and 10"):
        padded(windows, 10, scenes=3)


def _scenes(sizes, seed, box=None):
    scenes = [wandering_trajectory(particles=n, frames=14, seed=seed + k) for k, n in enumerate(sizes)]
    return [replace(s, key=f"s{seed}_{k}", bounds=box) for k, s in enumerate(scenes)]


@pytest.mark.parametrize("own_box", [False, True])
def test_batches_of_one_class_replay_one_capture_and_each_scene_is_its_own_rollout(own_box, counted):
    # 40 + 70 = 110 and 50 + 55 = 105 and 100 particles: all in the class of 112 particles and 2 scenes.
    if own_box:  # each batch in boxes of its own that the guard holds: the class's walls are rewritten per batch
        boxes = [np.array([[0.0, 0.55], [0.0, 1.0]], np.float32), np.array([[0.45, 1.0], [0.0, 0.6]], np.float32)]
        guard = RolloutGuard(small_simulator("radius", PAPER).setup, margin=0.0, on_violation="clamp")
    else:
        boxes, guard = [None, None], None
    batches = [_scenes((40, 70), 1, boxes[0]), _scenes((50, 55), 3, boxes[1]), _scenes((100,), 5, boxes[0])]
    model = small_simulator("radius_fixed_capacity", PAPER, acc_std=0.02)
    classes = CaptureClasses(scenes=2)
    results = [rollout_batch(model, scenes, capture=classes, guard=guard) for scenes in batches]
    assert len(classes.classes) == 1 and next(iter(classes.classes.values())).batches == 3
    assert len(counted) == 1, "one capture object for the class"
    held = 0
    for scenes, batched in zip(batches, results, strict=True):
        for scene, result in zip(scenes, batched, strict=True):
            alone = rollout(small_simulator("radius", PAPER, acc_std=0.02), scene, guard=guard)
            held += sum(len(v.particles) for v in alone.guard_violations)
            # Only the matrix products see the other rows: float32 rounding over 12 steps of ~0.5 m positions.
            np.testing.assert_allclose(result.predicted, alone.predicted, rtol=0, atol=1e-5)
            assert len(result.guard_violations) == len(alone.guard_violations)
    if own_box:
        assert held > 0, "no wall held a particle: the rewritten walls were not tested"


def test_classes_that_take_turns_keep_their_own_buffers_and_captures(counted):
    # Each class's capture writes what its searches needed into its own buffers' record: a class checked against
    # another's record would miss its own overflows and lose edges (the scenes outgrow buffers sized at 1.0).
    model = small_simulator("radius_fixed_capacity", PAPER, acc_std=0.02)
    classes = CaptureClasses(scenes=2)
    # 52 and 56 particles (the class of 56), 120 and 117 (128): the later batch of each class is the denser.
    batches = [_scenes((26, 26), 1), _scenes((60, 60), 3), _scenes((28, 28), 5), _scenes((55, 62), 7)]
    results = [rollout_batch(model, scenes, capture=classes) for scenes in batches]
    assert len(classes.classes) == 2 and len(counted) == 2
    for scenes, batched in zip(batches, results, strict=True):
        for scene, result in zip(scenes, batched, strict=True):
            alone = rollout(small_simulator("radius", PAPER, acc_std=0.02), scene)
            np.testing.assert_allclose(result.predicted, alone.predicted, rtol=0, atol=1e-5)
