"""The benchmark scene: one example of water particles on a jittered lattice.

2D: square lattice of spacing 0.0058 with +-15% uniform jitter per coordinate,
connectivity radius 0.015 (~19.5 neighbours per particle besides itself), the
WaterDrop statistics of the parity fixture, and 9 particle types in the model
(so node features carry the 16-wide type embedding, as the reference's
``_get_simulator`` builds it). 3D: cubic lattice, spacing chosen so that the
mean neighbour count is also ~20 at the same radius.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from gns_framework.contracts import ModelSetup
from gns_framework.data.batch import ParticleBatch
from gns_framework.data.metadata import DatasetMetadata

RADIUS = 0.015
SPACING = {2: 0.0058, 3: 0.0085}
"""Lattice spacing per dimension; 3D chosen for ~20 neighbours within R, as in 2D."""
JITTER = 0.15
HISTORY = 6
WATER = 5
PARTICLE_TYPES = tuple(range(9))
VEL_MEAN, VEL_STD = [5.12e-06, -9.97e-04], [2.20e-03, 2.67e-03]
ACC_MEAN, ACC_STD = [5.24e-07, 2.36e-07], [2.58e-04, 2.96e-04]
"""The parity fixture's WaterDrop-like statistics (the z component repeats y in 3D)."""


@dataclass(frozen=True)
class LatticeScene:
    setup: ModelSetup
    metadata: DatasetMetadata
    batch: ParticleBatch
    """A window with ``next_position``: training input and rollout state at once."""


def lattice_positions(particles: int, dim: int, generator: torch.Generator) -> torch.Tensor:
    """(N, d) float32: the first N sites of a jittered lattice as square/cubic as N allows."""
    side = math.ceil(particles ** (1 / dim))
    axes = torch.meshgrid(*[torch.arange(side, dtype=torch.float64)] * dim, indexing="ij")
    sites = torch.stack([a.reshape(-1) for a in axes], 1)[:particles]
    jitter = (torch.rand(sites.shape, generator=generator, dtype=torch.float64) * 2 - 1) * JITTER
    return ((sites + jitter) * SPACING[dim] + 0.1 + SPACING[dim]).float()


def lattice_scene(particles: int, dim: int = 2, seed: int = 0) -> LatticeScene:
    """The benchmark scene with N particles, walls just around the lattice."""
    generator = torch.Generator().manual_seed(seed)
    position = lattice_positions(particles, dim, generator)
    upper = float(position.max()) + SPACING[dim]
    bounds = tuple((0.1, upper) for _ in range(dim))
    vel_std = (VEL_STD + VEL_STD[1:])[:dim]
    acc_std = (ACC_STD + ACC_STD[1:])[:dim]
    vel_mean = (VEL_MEAN + VEL_MEAN[1:])[:dim]
    acc_mean = (ACC_MEAN + ACC_MEAN[1:])[:dim]
    metadata = DatasetMetadata(
        bounds=[list(b) for b in bounds],
        sequence_length=HISTORY + 1,
        default_connectivity_radius=RADIUS,
        dim=dim,
        dt=0.0025,
        vel_mean=vel_mean,
        vel_std=vel_std,
        acc_mean=acc_mean,
        acc_std=acc_std,
    )
    setup = ModelSetup(
        dim=dim, bounds=bounds, connectivity_radius=RADIUS, particle_types=PARTICLE_TYPES, history=HISTORY
    )
    # A small random walk so velocities and accelerations are realistic in size.
    velocity = torch.randn((particles, HISTORY, dim), generator=generator) * torch.tensor(vel_std)
    trajectory = position[:, None] + torch.cumsum(velocity, 1) - velocity.sum(1, keepdim=True)
    batch = ParticleBatch(
        position_sequence=trajectory[:, :HISTORY].contiguous(),
        particle_type=torch.full((particles,), WATER, dtype=torch.long),
        batch=torch.zeros(particles, dtype=torch.long),
        num_examples=1,
        next_position=trajectory[:, HISTORY - 1] + velocity[:, -1],
    )
    return LatticeScene(setup, metadata, batch)
