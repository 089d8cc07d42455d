"""Small physical scenes made in-process for tests: soft spheres under gravity in a box.

Discrete-element dynamics (linear repulsion between overlapping spheres, viscous
damping, inelastic walls), integrated with many substeps per stored frame. Small
and fast, yet real dynamics a GNS can learn.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gns_framework.data.metadata import DatasetMetadata, compute_statistics
from gns_framework.data.trajectory import Trajectory
from gns_framework.plugins import load_registry

RADIUS = 0.02
SPACING = 0.04
CONNECTIVITY_RADIUS = 0.06


def soft_sphere_trajectory(
    seed: int,
    dim: int = 2,
    frames: int = 40,
    block: int = 6,
    particle_types: tuple[int, ...] = (5,),
    kinematic_floor: bool = False,
    with_property: bool = False,
    key: str = "",
) -> Trajectory:
    """A block of ``block**dim`` particles falling and spreading in the unit box."""
    rng = np.random.default_rng(seed)
    grid = np.stack(np.meshgrid(*[np.arange(block)] * dim, indexing="ij"), -1).reshape(-1, dim)
    origin = rng.uniform(0.15, 0.85 - block * SPACING, size=dim)
    origin[-1] = rng.uniform(0.35, 0.5)
    position = origin + grid * SPACING + rng.normal(0, 0.002, grid.shape)
    velocity = np.tile(rng.normal(0, 0.3, dim), (len(position), 1))
    types = np.asarray(particle_types)[np.arange(len(position)) % len(particle_types)]
    moving = len(position)
    if kinematic_floor:
        xs = np.arange(0.12, 0.88, SPACING / 2)
        floor = np.zeros((len(xs), dim))
        floor[:, 0] = xs
        floor[:, -1] = 0.12
        position = np.concatenate([position, floor])
        velocity = np.concatenate([velocity, np.zeros_like(floor)])
        types = np.concatenate([types, np.full(len(xs), 3)])
    stiffness, damping, gravity = 2e4, 2.0, 9.81
    dt_frame, substeps = 0.01, 20
    dt = dt_frame / substeps
    frames_out = [position.copy()]
    for frame in range(1, frames):
        for _ in range(substeps):
            diff = position[:moving, None] - position[None]
            dist = np.linalg.norm(diff, axis=-1)
            np.fill_diagonal(dist[:, :moving], np.inf)
            overlap = np.clip(2 * RADIUS - dist, 0, None)
            force = (stiffness * overlap / np.maximum(dist, 1e-9))[..., None] * diff
            accel = force.sum(1) - damping * velocity[:moving]
            accel[:, -1] -= gravity
            velocity[:moving] += dt * accel
            position[:moving] += dt * velocity[:moving]
            low, high = position[:moving] < 0.1, position[:moving] > 0.9
            velocity[:moving] = np.where(low | high, -0.3 * velocity[:moving], velocity[:moving])
            position[:moving] = np.clip(position[:moving], 0.1, 0.9)
        if kinematic_floor:
            position[moving:, 0] = floor[:, 0] + 0.02 * np.sin(frame * 0.3)
        frames_out.append(position.copy())
    prop = None
    if with_property:
        prop = np.where(types == 3, 0.0, rng.uniform(0.4, 0.9)).astype(np.float32)[:, None]
    return Trajectory(np.asarray(frames_out, np.float32), types.astype(np.int64), prop, None, key).validated(
        "synthetic"
    )


def synthetic_metadata(trajectories: list[Trajectory], dim: int) -> DatasetMetadata:
    return DatasetMetadata(
        bounds=[(0.1, 0.9)] * dim,
        sequence_length=trajectories[0].num_steps,
        default_connectivity_radius=CONNECTIVITY_RADIUS,
        dim=dim,
        dt=0.01,
        **compute_statistics(trajectories, load_registry().kinematic_types()),
    )


def write_synthetic_dataset(
    path: Path, train: int = 4, valid: int = 2, test: int = 2, dim: int = 2, layout: str = "safe", **scene
) -> Path:
    """Generate and write a small dataset (train/valid/test + metadata.json)."""
    from gns_framework.plugins import load_registry

    counts = {"train": train, "valid": valid, "test": test}
    splits, seed = {}, 0
    for split, count in counts.items():
        splits[split] = []
        for i in range(count):
            splits[split].append(soft_sphere_trajectory(seed, dim=dim, key=f"{split}_{i:03d}", **scene))
            seed += 1
    metadata = synthetic_metadata(splits["train"], dim)
    load_registry().get("dataset", layout).write(path, metadata, splits)
    return path
