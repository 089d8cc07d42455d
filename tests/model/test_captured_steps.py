"""Rollouts replayed from one captured step (model/captured_steps.py, emulated on the CPU): the frames of the eager
rollout, a fresh capture after the graph builder grows its buffers, and a clear refusal where the step waits."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from fixed_capacity_cases import small_simulator, wandering_trajectory

from gns_framework.model.rollout import rollout
from gns_framework.runtime.capture import CaptureError

PAPER = {"name": "interaction_network", "message_passing_steps": 2, "edge_block": "plain"}


@pytest.mark.parametrize("edge_block", ["plain", "fused"])
def test_a_captured_rollout_gives_the_eager_frames_and_captures_again_after_growth(edge_block, counted):
    processor = {**PAPER, "edge_block": edge_block}
    trajectory = wandering_trajectory()
    eager = rollout(small_simulator("radius_fixed_capacity", processor, acc_std=0.02), trajectory)
    model = small_simulator("radius_fixed_capacity", processor, acc_std=0.02)
    captured = rollout(model, trajectory, capture=True)
    assert model.graph_builder.search.sizings > 1, "the scene never outgrew its buffers: make it"
    assert counted[0].captures >= 2, "grown buffers need a fresh capture"
    # plain: the same operations, bitwise; fused: eagerly the CPU's C kernels, captured the accelerators' torch
    # path, equal within float32 rounding of positions ~0.5 m.
    tolerance = 0.0 if edge_block == "plain" else 1e-5
    np.testing.assert_allclose(captured.predicted, eager.predicted, rtol=0, atol=tolerance)


def test_a_step_that_waits_for_the_device_is_refused_naming_the_builder_to_use(counted):
    with pytest.raises(CaptureError, match=r"reads back.*use radius_fixed_capacity"):
        rollout(small_simulator("radius", PAPER), wandering_trajectory(frames=10), capture=True)


def test_a_captured_batch_gives_each_scene_its_own_rollout(counted):
    # Issue 45, item 5: many small scenes stepped as one batch, replayed from one capture, each its own frames.
    from gns_framework.model.batched_rollout import rollout_batch

    model = small_simulator("radius_fixed_capacity", PAPER, acc_std=0.02)
    scenes = [wandering_trajectory(particles=n, frames=16, seed=seed) for n, seed in ((40, 1), (70, 2), (25, 3))]
    scenes = [replace(scene, key=f"scene_{k}") for k, scene in enumerate(scenes)]
    batched = rollout_batch(model, scenes, capture=True)
    assert counted and counted[0].captures >= 1
    for scene, result in zip(scenes, batched, strict=True):
        alone = rollout(small_simulator("radius", PAPER, acc_std=0.02), scene)
        # Only the matrix products see the other scenes' rows: float32 rounding over 10 steps of ~0.5 m positions.
        np.testing.assert_allclose(result.predicted, alone.predicted, rtol=0, atol=1e-5)


def test_a_grid_processor_that_reads_back_is_refused_naming_its_line_not_the_builder(counted):
    from fixed_capacity_cases import SETUP
    from rollouts import small_metadata

    from gns_framework.assembly.learned import build_learned_simulator
    from gns_framework.config.recipe import ModelSpec
    from gns_framework.plugins import load_registry

    spec = ModelSpec(
        latent_size=8,
        mlp_hidden_size=8,
        mlp_hidden_layers=1,
        graph_builder={"name": "no_edges"},
        processor={"name": "grid_cnn", "message_passing_steps": 1},
    )
    model = build_learned_simulator(SETUP, small_metadata(), spec, load_registry()).eval()
    with pytest.raises(CaptureError, match=r"grid_cnn\.py") as refused:
        rollout(model, wandering_trajectory(frames=10), capture=True)
    assert "radius_fixed_capacity" not in str(refused.value)  # no_edges does not wait: the hint would mislead
