"""Small rollouts and metadata built in memory, for the evaluation, file and picture tests."""

from __future__ import annotations

import numpy as np

from gns_framework.data.metadata import DatasetMetadata
from gns_framework.data.rollout import Rollout
from gns_framework.data.trajectory import Trajectory


def small_metadata(dim: int = 2, dt: float = 0.01) -> DatasetMetadata:
    return DatasetMetadata(
        bounds=[(0.0, 1.0)] * dim,
        sequence_length=20,
        default_connectivity_radius=0.1,
        dim=dim,
        dt=dt,
        vel_mean=[0.0] * dim,
        vel_std=[1.0] * dim,
        acc_mean=[0.0] * dim,
        acc_std=[1.0] * dim,
    )


def small_rollout(dim: int = 2, steps: int = 8, particles: int = 12, history: int = 6, seed: int = 0) -> Rollout:
    """Particles drifting inside the unit box; the prediction is the truth plus a growing offset.

    Types: the last two particles are kinematic (3), the rest sand (6); two material properties.
    """
    rng = np.random.default_rng(seed)
    start = rng.uniform(0.2, 0.8, size=(particles, dim))
    velocity = rng.normal(0.0, 0.002, size=(particles, dim))
    frames = start + velocity * np.arange(history + steps)[:, None, None]
    particle_type = np.full(particles, 6, dtype=np.int64)
    particle_type[-2:] = 3
    offset = 0.001 * np.arange(1, steps + 1)[:, None, None] * np.ones((1, particles, dim))
    offset[:, -2:] = 0.0
    material_property = rng.uniform(0.5, 1.0, size=(particles, 2)).astype(np.float32)
    return Rollout(
        truth=Trajectory(frames.astype(np.float32), particle_type, material_property, key="memory"),
        predicted=(frames[history:] + offset).astype(np.float32),
        history=history,
        metadata=small_metadata(dim),
        source="memory.npz",
    )
