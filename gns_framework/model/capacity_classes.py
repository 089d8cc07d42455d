"""Capacity classes: batches of similar size replay one captured step (issue 45, item 5).

A captured step (a CUDA graph) runs on the shapes it was captured with. Batches of
small scenes differ in particle count, so each would be captured afresh, and a capture
costs about as much as the tens of steps a small scene's rollout takes. Here a batch
is padded to its class instead: the particle count rounded up on a ladder of steps of
at most 25 % (8, 10, 12, 14, 16, 20, 24, 28, 32, ...), the example count to the
largest batch. Padding particles stand in an example of their own after the scenes,
with non-finite (NaN) positions: every graph builder joins them to no one, so each
scene's graph, and its frames, are those of its batch alone. The class keeps its
capture, the graph builder's buffers of fixed size, the walls the step's guard reads
and the rows whose next positions are given; a later batch of the class copies its
own into them and replays.

Shapes: a class of capacity N_cap and B_cap scenes steps (N_cap, C, d) windows of
B_cap + 1 examples; ``truth`` (S, N_cap, d) gives every row's next position (the
moving rows' are not used).
"""

from __future__ import annotations

from collections.abc import Hashable, Sequence
from dataclasses import dataclass, fields, replace
from typing import Any

import torch
from torch import Tensor

from ..data.batch import ParticleBatch, collate
from ..runtime.precision import Precision
from .captured_steps import CapturedSteps
from .learned_simulator import LearnedSimulator
from .rollout import captured_rollout_steps
from .rollout_guard import RolloutGuard

RUNGS = (4, 5, 6, 7)
"""Capacities are 2^k * (4, 5, 6, 7) / 4: no class is more than 25 % above the batches it holds."""


def particle_capacity(count: int) -> int:
    """The least capacity of the ladder (8, 10, 12, 14, 16, 20, ...) that holds ``count`` particles."""
    base = 2
    while True:
        for rung in RUNGS:
            if base * rung >= count:
                return base * rung
        base *= 2


def class_key(state: ParticleBatch, precision: Precision) -> tuple:
    """A padded batch's class: the shapes of everything a captured step of it reads, and its precision."""
    shapes = tuple((f.name, tuple(v.shape)) for f in fields(state) if isinstance(v := getattr(state, f.name), Tensor))
    return (state.num_examples, shapes, precision)


def padded(windows: Sequence[ParticleBatch], capacity: int, scenes: int) -> ParticleBatch:
    """The scenes' one-example windows stacked, then ``scenes - len(windows)`` empty examples and one example of
    ``capacity - N`` padding particles (NaN positions; the last scene's type, properties and walls)."""
    last = windows[-1]
    count = sum(w.num_particles for w in windows)
    if len(windows) > scenes or count > capacity:
        raise ValueError(f"{len(windows)} scenes of {count} particles exceed a class of {scenes} and {capacity}")
    fillers = [_like(last, 0)] * (scenes - len(windows)) + [_like(last, capacity - count)]
    return collate([*windows, *fillers])


def _like(example: ParticleBatch, particles: int) -> ParticleBatch:
    """An example of ``particles`` rows at NaN, with the last row's type and properties and ``example``'s walls."""
    per_particle = {"position_sequence", "particle_type", "material_property"}
    rows: dict[str, Any] = {
        f.name: value[-1:].expand(particles, *value.shape[1:]).clone()
        for f in fields(example)
        if f.name in per_particle and isinstance(value := getattr(example, f.name), Tensor)
    }
    rows["position_sequence"] = torch.full_like(rows["position_sequence"], float("nan"))
    return replace(
        example, **rows, batch=torch.zeros(particles, dtype=torch.long), next_position=None, ahead=None, num_examples=1
    )


@dataclass
class CapacityClass:
    """What one class keeps between its batches.

    Attributes:
        key: the class (also the graph builder's key for its buffers of fixed size).
        steps: the captured step, made by its first batch.
        guard: the guard the step reads, walls per row (rewritten for each batch) or the model's.
        every_row: (N_cap,) the rows whose next positions the step is given: all of them.
        batches: how many batches the class has stepped.
    """

    key: Hashable
    steps: CapturedSteps
    guard: RolloutGuard
    every_row: Tensor
    batches: int = 0


class CaptureClasses:
    """One captured rollout step per capacity class, kept for every batch that falls in it.

    Args:
        scenes: the most scenes a batch holds (``gns rollout --batch``).
    """

    def __init__(self, scenes: int):
        if scenes < 1:
            raise ValueError(f"a class holds at least one scene, not {scenes}")
        self.scenes = scenes
        self.classes: dict[Hashable, CapacityClass] = {}

    def of(
        self,
        simulator: LearnedSimulator,
        guard: RolloutGuard,
        state: ParticleBatch,
        bounds: Tensor | None,
        precision: Precision,
    ) -> CapacityClass:
        """The class of the padded batch ``state`` (on its device), made on its first batch; ``bounds`` (N_cap, d, 2)
        are its rows' walls (None: the model's), ``guard`` the batch's guard without them."""
        key = class_key(state, precision)
        kept = self.classes.get(key)
        if kept is None:
            walled = guard if bounds is None else guard.with_bounds(bounds)
            every_row = torch.arange(state.num_particles, device=state.position_sequence.device)
            steps = captured_rollout_steps(simulator, walled, state, every_row, precision)
            kept = self.classes[key] = CapacityClass(key, steps, walled, every_row)
        elif bounds is not None:
            kept.guard.rewrite_bounds(bounds)
        kept.batches += 1
        return kept
