"""Training windows and their order: deterministic from (seed, step), so resuming is exact."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from .batch import ParticleBatch, collate, window
from .trajectory import Trajectory

Shapes = Sequence[tuple[int, int]] | None


class WindowIndex:
    """Every window ``[start, start + C + ahead]`` (C inputs, 1 target, ``ahead`` later frames) of every trajectory.

    ``ahead`` > 0 keeps the true frames after the target for push-forward and the unrolled loss
    (``ParticleBatch.ahead``). ``shapes``: each trajectory's (frames, particles), when known without reading it.
    """

    def __init__(self, trajectories: Sequence[Trajectory], history: int, ahead: int = 0, shapes: Shapes = None):
        self.trajectories = trajectories
        self.history = history
        self.ahead = ahead
        shapes = shapes if shapes is not None else [(t.num_steps, t.num_particles) for t in trajectories]
        pairs = [(i, s) for i, (frames, _) in enumerate(shapes) for s in range(frames - history - ahead)]
        if not pairs:
            raise ValueError(f"no trajectory has more than history + frames ahead = {history + ahead} frames")
        self.pairs = np.asarray(pairs, dtype=np.int64)
        self._particles = np.asarray([particles for _, particles in shapes], dtype=np.int64)

    def __len__(self) -> int:
        return len(self.pairs)

    def num_particles(self, index: int) -> int:
        """Particles of window ``index``, without loading it."""
        return int(self._particles[self.pairs[index, 0]])

    def example(self, index: int) -> ParticleBatch:
        trajectory, start = self.pairs[index]
        return window(self.trajectories[trajectory], int(start), self.history, ahead=self.ahead)

    def batch(self, indices: Sequence[int] | np.ndarray) -> ParticleBatch:
        return collate([self.example(i) for i in indices])


class WindowOrder:
    """Which windows each process trains on at each step: a distributed sampler driven by the step.

    Windows are shuffled once per epoch with a generator seeded by (seed, epoch);
    step ``s`` takes the global positions ``[s*G, (s+1)*G)`` of the concatenated
    epochs (G = batch size x world size) and process ``rank`` its own B of them, so
    processes see disjoint shards of every epoch. This is what a DistributedSampler
    with ``set_epoch`` gives, but derived from the step alone, so a run resumed in
    the middle of an epoch continues with exactly the data it would have seen.
    """

    def __init__(self, num_windows: int, batch_size: int, seed: int, rank: int = 0, world_size: int = 1):
        self.num_windows, self.batch_size, self.seed = num_windows, batch_size, seed
        self.rank, self.world_size = rank, world_size
        self._shuffled: tuple[int, np.ndarray] = (-1, np.empty(0, np.int64))  # the last epoch's permutation

    def permutation(self, epoch: int) -> np.ndarray:
        if self._shuffled[0] != epoch:
            generator = torch.Generator().manual_seed(self.seed * 1_000_003 + epoch)
            self._shuffled = (epoch, torch.randperm(self.num_windows, generator=generator).numpy())
        return self._shuffled[1]

    def draw(self, step: int) -> StepWindows:
        """Step ``step``'s global batch: positions ``[s*G, (s+1)*G)`` of the stream, rank-major, and this rank's
        share."""
        size = self.batch_size * self.world_size
        positions = range(step * size, (step + 1) * size)
        every = [int(self.permutation(p // self.num_windows)[p % self.num_windows]) for p in positions]
        first = self.rank * self.batch_size
        return StepWindows(step, every, range(first, first + self.batch_size))


@dataclass(frozen=True)
class StepWindows:
    """Step ``step``'s windows: ``every`` (W x B indices of its global batch, rank-major), this process's ``slots``."""

    step: int
    every: list[int]
    slots: range

    @property
    def mine(self) -> list[int]:
        return [self.every[slot] for slot in self.slots]
