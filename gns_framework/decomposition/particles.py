"""The particles one process holds in a domain decomposition: global ids and the per-particle fields that travel."""

from __future__ import annotations

from dataclasses import dataclass, fields

import torch
from torch import Tensor


@dataclass(frozen=True)
class Particles:
    """n particles of the scene, any order. Fields the scene or the step does not have are None.

    Shapes: ids (n,) int64 index in the whole batch (example after example, as collated);
    sequence (n, C, d) positions; particle_type (n,) int64; material_property (n, P);
    next_position (n, d) the training target; noise (n, C, d) the training noise added to
    ``sequence``; example (n,) int64 the example of each particle in a batch of several.
    """

    ids: Tensor
    sequence: Tensor
    particle_type: Tensor
    material_property: Tensor | None = None
    next_position: Tensor | None = None
    noise: Tensor | None = None
    example: Tensor | None = None

    @property
    def count(self) -> int:
        return int(self.ids.shape[0])

    def columns(self) -> list[Tensor | None]:
        """Every field, in declaration order (what :func:`.exchange.send_rows` sends)."""
        return [getattr(self, f.name) for f in fields(self)]

    @classmethod
    def of(cls, columns: list[Tensor | None]) -> Particles:
        ids, sequence, particle_type, *rest = columns
        assert ids is not None and sequence is not None and particle_type is not None
        return cls(ids, sequence, particle_type, *rest)

    def select(self, rows: Tensor) -> Particles:
        """The particles at ``rows`` (indices or a bool mask)."""
        return Particles.of([None if c is None else c[rows] for c in self.columns()])

    def cat(self, other: Particles) -> Particles:
        """These particles, then ``other``'s: both must have the same fields."""
        return Particles.of([_cat(a, b) for a, b in zip(self.columns(), other.columns(), strict=True)])

    def to(self, device: torch.device) -> Particles:
        return Particles.of([None if c is None else c.to(device) for c in self.columns()])


def _cat(first: Tensor | None, second: Tensor | None) -> Tensor | None:
    assert (first is None) == (second is None), "particles of one scene carry the same fields"
    return None if first is None or second is None else torch.cat([first, second])
