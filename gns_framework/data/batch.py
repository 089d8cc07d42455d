"""A batch of training windows (or rollout states): several examples with their particles stacked."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields, replace

import numpy as np
import torch
from torch import Tensor

from .trajectory import Trajectory


@dataclass(frozen=True)
class ParticleBatch:
    """B examples, N particles in all, stored example after example.

    Attributes:
        position_sequence: (N, C, d) float32, the last C positions (particle-major).
        particle_type: (N,) int64.
        batch: (N,) int64 example index of every particle (non-decreasing).
        num_examples: B.
        next_position: (N, d) the position after the window (training label), or None.
        material_property: (N, P) float32 or None.
        context: (B, c) float32 global context of each example's last input frame, or None.
        ahead: (N, m, d) float32 the m true positions after ``next_position`` (push-forward, unrolled loss), or None.
        bounds: (B, d, 2) float32 each example's domain (its walls), or None (the model's bounds).
        walls: (B, 2d, 2) float32 each example's face conditions (friction, no-slip flag), or None.
        owned: (N,) bool, the particles this process owns in a piece of a scene split with a halo of latents
            (:mod:`gns_framework.decomposition.piece`), the graph's only receivers; or None.
        exchange: with ``owned``, refreshes the halo's node latents from their owners (``Graph.exchange``).
    """

    position_sequence: Tensor
    particle_type: Tensor
    batch: Tensor
    num_examples: int
    next_position: Tensor | None = None
    material_property: Tensor | None = None
    context: Tensor | None = None
    ahead: Tensor | None = None
    bounds: Tensor | None = None
    walls: Tensor | None = None
    owned: Tensor | None = None
    exchange: Callable[[Tensor], Tensor] | None = None

    @property
    def num_particles(self) -> int:
        return int(self.position_sequence.shape[0])

    def _map_tensors(self, convert) -> ParticleBatch:
        """The same batch with ``convert`` applied to every tensor field (None fields stay None)."""
        return replace(
            self,
            **{f.name: convert(value) for f in fields(self) if isinstance(value := getattr(self, f.name), Tensor)},
        )

    def pinned(self) -> ParticleBatch:
        """The same batch in page-locked host memory, so copies to a GPU need not block the host."""
        return self._map_tensors(lambda t: t.pin_memory())

    def to(self, device: torch.device | str) -> ParticleBatch:
        return self._map_tensors(lambda t: t.to(device, non_blocking=True))


def window(trajectory: Trajectory, start: int, history: int, with_target: bool = True, ahead: int = 0) -> ParticleBatch:
    """The window ``[start, start + history)`` of a trajectory as a batch of one example.

    With a target, ``ahead`` > 0 also keeps the ``ahead`` true frames after it. Frames are copied: they may be
    a read-only memory map of the file (``dataset.memory: windows``), which checks its file is unchanged first.
    """
    positions = np.array(trajectory.position[start : start + history + (1 + ahead if with_target else 0)])
    sequence = torch.from_numpy(np.ascontiguousarray(positions[:history].transpose(1, 0, 2)))
    n = sequence.shape[0]
    return ParticleBatch(
        position_sequence=sequence,
        particle_type=torch.from_numpy(trajectory.particle_type),
        batch=torch.zeros(n, dtype=torch.long),
        num_examples=1,
        next_position=torch.from_numpy(np.ascontiguousarray(positions[history])) if with_target else None,
        material_property=None
        if trajectory.material_property is None
        else torch.from_numpy(trajectory.material_property),
        context=None
        if trajectory.step_context is None
        else torch.from_numpy(trajectory.step_context[start + history - 1])[None],
        ahead=torch.from_numpy(np.ascontiguousarray(positions[history + 1 :].transpose(1, 0, 2)))
        if with_target and ahead
        else None,
        bounds=None if trajectory.bounds is None else torch.from_numpy(np.asarray(trajectory.bounds, np.float32))[None],
        walls=None if trajectory.walls is None else torch.from_numpy(np.asarray(trajectory.walls, np.float32))[None],
    )


def collate(examples: Sequence[ParticleBatch]) -> ParticleBatch:
    """Stack single- or multi-example batches into one; examples never share edges."""
    offsets = np.cumsum([0] + [e.num_examples for e in examples])
    cat = lambda name: None if getattr(examples[0], name) is None else torch.cat([getattr(e, name) for e in examples])  # noqa: E731
    return ParticleBatch(
        position_sequence=torch.cat([e.position_sequence for e in examples]),
        particle_type=torch.cat([e.particle_type for e in examples]),
        batch=torch.cat([e.batch + int(o) for e, o in zip(examples, offsets[:-1], strict=True)]),
        num_examples=int(offsets[-1]),
        next_position=cat("next_position"),
        material_property=cat("material_property"),
        context=cat("context"),
        ahead=cat("ahead"),
        bounds=_cat_per_example(examples, "bounds"),
        walls=_cat_per_example(examples, "walls"),
    )


def _cat_per_example(examples: Sequence[ParticleBatch], name: str) -> Tensor | None:
    """Per-example rows of ``name`` stacked; None when no example has them.

    Examples from datasets that record their domain mix only with others that do: a batch
    where some examples have bounds and some not would give the model two kinds of walls.
    """
    present = [getattr(e, name) is not None for e in examples]
    if not any(present):
        return None
    if not all(present):
        raise ValueError(f"collate: some examples have {name} and some not; every example needs its own {name}")
    return torch.cat([getattr(e, name) for e in examples])
