"""A small model on either radius builder and a scene that outgrows its first graph, for the fixed-capacity and
captured-step tests."""

from __future__ import annotations

import numpy as np
import torch
from rollouts import small_metadata

from gns_framework.assembly.learned import build_learned_simulator
from gns_framework.config.recipe import ModelSpec
from gns_framework.contracts import ModelSetup
from gns_framework.data.trajectory import Trajectory
from gns_framework.plugins import load_registry

SETUP = ModelSetup(dim=2, bounds=((0.0, 1.0), (0.0, 1.0)), connectivity_radius=0.1, particle_types=(5,))


def small_simulator(builder: str, processor: dict, acc_std: float = 0.001):
    """A small untrained 2D model with ``builder`` (fixed-capacity builders at capacity 1.0: overflows come soon)."""
    metadata = small_metadata().model_copy(update={"vel_std": [0.01, 0.01], "acc_std": [acc_std, acc_std]})
    torch.manual_seed(0)
    spec = ModelSpec(
        latent_size=8,
        mlp_hidden_size=8,
        mlp_hidden_layers=1,
        graph_builder={"name": builder, **({"capacity": 1.0} if builder != "radius" else {})},
        processor=processor,
    )
    return build_learned_simulator(SETUP, metadata, spec, load_registry()).eval()


def wandering_trajectory(particles: int = 150, frames: int = 30, seed: int = 4) -> Trajectory:
    """A random walk of particles in the middle of the box: a model with large accelerations spreads and
    squeezes them, so a later frame needs more pairs than the first."""
    generator = np.random.default_rng(seed)
    start = 0.3 + 0.4 * generator.random((1, particles, 2))
    position = start + 0.002 * generator.standard_normal((frames, particles, 2)).cumsum(0)
    return Trajectory(position.astype(np.float32), np.full(particles, 5), None, None, "t")
