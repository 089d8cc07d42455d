"""Random-walk training noise on the input positions (Sanchez-Gonzalez et al. 2020, Sec. 3): its std and its draw."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import torch
from torch import Tensor

if TYPE_CHECKING:
    from ..config.recipe import ModelSpec
    from ..data.metadata import DatasetMetadata
    from ..data.windows import StepWindows


def random_walk_noise(
    position_sequence: Tensor, noise_std_last_step: float, generator: torch.Generator | None = None
) -> Tensor:
    """Noise for a (N, C, d) position history whose velocities follow a random walk.

    Velocity noise is a random walk: a cumulative sum of C - 1 independent N(0, (sigma / sqrt(C - 1))^2)
    increments, so the last velocity's noise has std sigma. Position noise integrates the velocity
    noise (a second cumulative sum) from a noise-free first position.

    Returns:
        (N, C, d) position noise, same dtype and device as the input.
    """
    n, c, d = position_sequence.shape
    num_velocities = c - 1
    velocity_noise = torch.randn(
        (n, num_velocities, d), generator=generator, dtype=position_sequence.dtype, device=position_sequence.device
    ) * (noise_std_last_step / num_velocities**0.5)
    velocity_noise = torch.cumsum(velocity_noise, dim=1)
    return torch.cat([torch.zeros_like(velocity_noise[:, :1]), torch.cumsum(velocity_noise, dim=1)], dim=1)


def training_noise_std(model: ModelSpec, metadata: DatasetMetadata) -> float:
    """The random-walk noise std of a model's recipe, in dataset length units per frame.

    ``noise_relative`` scales with the data: the reference's absolute 6.7e-4 was tuned for DeepMind's datasets, and
    on data with slower particles the same value drowns the velocity signal. The std enters the input normalisation
    too, so a checkpoint rebuilds the same value from its stored metadata.
    """
    if model.noise_relative is None:
        return model.noise_std
    return model.noise_relative * sum(metadata.vel_std) / len(metadata.vel_std)


def step_noise(drawn: StepWindows, particles: Sequence[int], shape: tuple[int, int], std: float, seed: int) -> Tensor:
    """This process's noise of a step on the host, (sum of ``particles``, C, d) float32; ``shape``: (C, d).

    ``particles``: of each window of ``drawn.mine``, whose generators are seeded by (seed, step, slot in the
    global batch): W processes of B windows get exactly one process's noise of the same W x B windows.
    """
    parts = [
        random_walk_noise(torch.empty((n, *shape)), std, window_noise_generator(seed, drawn.step, slot))
        for n, slot in zip(particles, drawn.slots, strict=True)
    ]
    return torch.cat(parts)


def window_noise_generator(seed: int, step: int, slot: int) -> torch.Generator:
    """Noise generator of the window in ``slot`` of step ``step``'s global batch (rank-major)."""
    state = np.random.SeedSequence([seed, 1, step, slot]).generate_state(2, dtype=np.uint32)
    return torch.Generator().manual_seed(int(state[0]) << 32 | int(state[1]))
