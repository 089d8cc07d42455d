"""Periodic domains: continuous histories, minimum-image targets, training and rollouts."""

from __future__ import annotations

import dataclasses

import numpy as np
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from synthetic import soft_sphere_trajectory, synthetic_metadata
from tiny import tiny_recipe, tiny_trainer

from gns_framework.data.metadata import compute_statistics
from gns_framework.model.periodic import PeriodicBox
from gns_framework.model.rollout import rollout
from gns_framework.plugins import load_registry
from gns_framework.testing import small_scene

BOX = PeriodicBox(small_scene(2, periodic=(True, False)))


@settings(max_examples=50, deadline=None)
@given(
    arrays("float64", (4, 6, 2), elements=st.floats(-0.2, 0.2)), arrays("float64", (4, 2), elements=st.floats(-3, 3))
)
def test_unwrapping_a_wrapped_history_recovers_its_steps(steps, start):
    continuous = torch.from_numpy(start)[:, None] + torch.cumsum(torch.from_numpy(steps), 1)
    unwrapped = BOX.unwrap_history(BOX.wrap(continuous))
    assert torch.allclose(unwrapped[:, 1:] - unwrapped[:, :-1], continuous[:, 1:] - continuous[:, :-1], atol=1e-9)
    assert torch.allclose(unwrapped[:, -1], BOX.wrap(continuous[:, -1]))
    in_box = BOX.wrap(continuous)[..., 0]
    assert bool(((in_box >= 0) & (in_box < 1)).all())


def drifting_trajectory(seed: int, key: str):
    """Soft spheres drifting along x through the x-periodic faces of the box [0.1, 0.9]."""
    traj = soft_sphere_trajectory(seed, dim=2, frames=30, key=key)
    drift = 0.011 * np.arange(traj.num_steps, dtype=np.float32)[:, None]
    position = traj.position.copy()
    position[..., 0] += drift
    return dataclasses.replace(traj, position=position)


def wrapped(traj):
    position = traj.position.copy()
    position[..., 0] = 0.1 + np.mod(position[..., 0] - 0.1, 0.8)
    return dataclasses.replace(traj, position=position)


def test_periodic_scene_trains_and_rolls_out_inside_the_box(tmp_path):
    splits = {
        s: [drifting_trajectory(i, f"{s}_{i}") for i in range(n)] for s, n in (("train", 2), ("valid", 1), ("test", 1))
    }
    statistics = compute_statistics(splits["train"], load_registry().kinematic_types())
    metadata = synthetic_metadata(splits["train"], 2).model_copy(update=statistics)
    metadata = metadata.model_copy(update={"periodic_boundary_conditions": [True, False]})
    registry = load_registry()
    registry.get("dataset", "safe").write(
        tmp_path / "data", metadata, {s: [wrapped(t) for t in ts] for s, ts in splits.items()}
    )
    assert any(np.abs(np.diff(wrapped(t).position[..., 0], axis=0)).max() > 0.5 for t in splits["train"])

    trainer = tiny_trainer(tiny_recipe(tmp_path / "data", graph_builder={"name": "periodic_radius"}), tmp_path / "run")
    scene = trainer.simulator.setup
    assert scene.periodic_dims == (0,) and scene.wall_dims == (1,)
    losses = trainer.train(5)
    # Wrapped jumps of 0.8 would give normalised targets in the thousands.
    assert max(losses) < 100

    result = rollout(trainer.simulator, trainer.data.dataset.split("test")[0], steps=8)
    assert ((result.predicted[..., 0] >= 0.1) & (result.predicted[..., 0] < 0.9)).all()


def test_a_periodic_scene_refuses_a_builder_that_ignores_periodicity(tmp_path):
    import pytest
    from synthetic import write_synthetic_dataset

    from gns_framework.errors import RecipeError

    data = write_synthetic_dataset(tmp_path / "data", train=1, valid=0, test=0, frames=12)
    with pytest.raises(RecipeError, match="periodic_radius"):
        tiny_trainer(tiny_recipe(data, periodic=[True, False]), tmp_path / "run")
