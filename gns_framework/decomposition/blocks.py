"""Blocks: the domain cut by recursive coordinate bisection into P boxes of about equal particle count.

The particles are halved (in proportion to the processes on each side) by a plane across
the dimension in which they spread farthest, then each half is cut the same way, until
there is one box per process. Slabs (:mod:`.slabs`) make every piece as long as the whole
domain and only ``1/P`` as thick, so the halo, which is a fixed depth on each face, grows
in proportion to P; a box keeps its surface, and with it the halo, near
``N^((d-1)/d) P^(1/d)`` particles in all. Where the particles spread far more in one
dimension than the others, the first cuts are all across it and the blocks are slabs.

Process r owns the particles in box r, ``lower <= x < upper`` in every dimension (the
faces at the domain's edge are open, so every position has one owner). Its halo is every
particle of another box whose Euclidean distance to the box is at most ``depth``
(through the periodic faces where a dimension wraps around): the particles within the
receptive field of some particle the process owns.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Unpack

import torch
from torch import Tensor

from .space import CutOptions, check_parts, distance_to_interval, periodic_boxes
from .work import halo_cut, quantile_cut

CHUNK = 65_536
"""Particles compared with every box at once: (CHUNK, P, d) float64 temporaries, 100 MB at P = 64 in 3D."""


@dataclass(frozen=True)
class BlockPartition:
    """P axis-aligned boxes that tile space.

    Attributes:
        lower, upper: each box's faces, P tuples of d floats (dataset length units); faces
            at the domain's edge are -inf and inf.
        depth: halo depth (length units).
        box: per dimension, ``(lower, upper)`` of the periodic box where it wraps around, else None.
    """

    lower: tuple[tuple[float, ...], ...]
    upper: tuple[tuple[float, ...], ...]
    depth: float
    box: tuple[tuple[float, float] | None, ...]

    @property
    def parts(self) -> int:
        return len(self.lower)

    def describe(self) -> str:
        return f"{self.parts} blocks (recursive bisection)"

    @classmethod
    def balanced(cls, position: Tensor, parts: int, depth: float, **options: Unpack[CutOptions]) -> BlockPartition:
        """Boxes by recursive bisection of ``position`` (N, d): each cut halves the particles' ``weight`` (N,; default:
        their count), in proportion to the processes on either side, across the dimension they spread farthest in;
        ``bounds`` gives the periodic box of ``periodic_dims``."""
        check_parts(parts)
        dim = int(position.shape[1])
        box = periodic_boxes(dim, options)
        weight, halo = options.get("weight"), options.get("halo_weight")
        lower: list[tuple[float, ...]] = []
        upper: list[tuple[float, ...]] = []
        cutting = _Cutting(weight, halo, float(depth))
        _bisect(position.detach().to(torch.float64), cutting, parts, [-math.inf] * dim, [math.inf] * dim, lower, upper)
        return cls(tuple(lower), tuple(upper), float(depth), tuple(box))

    def owner(self, position: Tensor) -> Tensor:
        """(N,) int64 box of each position (N, d)."""
        lower, upper = self._faces(position.device)
        owners = []
        for rows in position.split(CHUNK):
            x = rows.to(torch.float64)[:, None, :]
            inside = ((x >= lower) & (x < upper)).all(dim=-1)
            owners.append(inside.to(torch.uint8).argmax(dim=1))
        return torch.cat(owners) if owners else torch.zeros(0, dtype=torch.long, device=position.device)

    def halo_of(self, position: Tensor) -> Tensor:
        """(N, P) bool: row i, column r is True when particle i lies within ``depth`` of box r but outside it."""
        parts = [self._halo_of(rows) for rows in position.split(CHUNK)]
        return torch.cat(parts) if parts else torch.zeros((0, self.parts), dtype=torch.bool, device=position.device)

    def _halo_of(self, position: Tensor) -> Tensor:
        """:meth:`halo_of` of at most :data:`CHUNK` particles: (n, P, d) distances in memory at once."""
        x = position.to(torch.float64)[:, None, :]
        lower, upper = self._faces(position.device)
        # The faces at a periodic box's edge: distances across them go through the wrap-around.
        for k, wrap in enumerate(self.box):
            if wrap is not None:
                lower[:, k] = lower[:, k].clamp(min=wrap[0])
                upper[:, k] = upper[:, k].clamp(max=wrap[1])
        gap = distance_to_interval(x, lower, upper)
        for k, wrap in enumerate(self.box):
            if wrap is not None:
                length = wrap[1] - wrap[0]
                for image in (x[..., k] + length, x[..., k] - length):
                    nearer = distance_to_interval(image[..., None], lower[:, k : k + 1], upper[:, k : k + 1])
                    gap[..., k] = torch.minimum(gap[..., k], nearer[..., 0])
        near = gap.square().sum(dim=-1) <= self.depth**2
        near[torch.arange(position.shape[0], device=position.device), self.owner(position)] = False
        return near

    def _faces(self, device: torch.device) -> tuple[Tensor, Tensor]:
        """(P, d) lower and upper faces, float64 on ``device``."""
        lower = torch.tensor(self.lower, dtype=torch.float64, device=device).reshape(self.parts, -1)
        upper = torch.tensor(self.upper, dtype=torch.float64, device=device).reshape(self.parts, -1)
        return lower, upper


@dataclass(frozen=True)
class _Cutting:
    """What a bisection weighs of the particles it cuts: their work and their halo's (either None: not weighed)."""

    weight: Tensor | None
    halo: Tensor | None
    depth: float

    def cut(self, coordinate: Tensor, below: int, parts: int) -> float:
        if self.halo is None:
            return quantile_cut(coordinate, self.weight, below, parts)
        return halo_cut(coordinate, self.weight, self.halo, self.depth, below, parts)

    def select(self, rows: Tensor) -> _Cutting:
        weight, halo = self.weight, self.halo
        return _Cutting(None if weight is None else weight[rows], None if halo is None else halo[rows], self.depth)


def _bisect(
    position: Tensor,
    cutting: _Cutting,
    parts: int,
    lower: list[float],
    upper: list[float],
    lowers: list[tuple[float, ...]],
    uppers: list[tuple[float, ...]],
) -> None:
    """Append the ``parts`` boxes of the particles ``position`` (n, d) inside ``[lower, upper)``, each cut where
    ``cutting`` balances their work, lower side first."""
    if parts == 1:
        lowers.append(tuple(lower))
        uppers.append(tuple(upper))
        return
    below = parts // 2
    n = int(position.shape[0])
    if n:
        spread = position.max(0).values - position.min(0).values
        axis = int(torch.argmax(spread))
        cut = cutting.cut(position[:, axis], below, parts)
    else:
        # No particle left to share (fewer particles than processes): the boxes only need to tile space.
        axis = 0
        cut = _middle(lower[axis], upper[axis])
    first = position[:, axis] < cut
    mine, theirs = cutting.select(first), cutting.select(~first)
    _bisect(position[first], mine, below, lower, [*upper[:axis], cut, *upper[axis + 1 :]], lowers, uppers)
    _bisect(position[~first], theirs, parts - below, [*lower[:axis], cut, *lower[axis + 1 :]], upper, lowers, uppers)


def _middle(low: float, high: float) -> float:
    """The middle of ``[low, high)``, or its finite face, or 0 when both are open."""
    if math.isfinite(low) and math.isfinite(high):
        return (low + high) / 2
    if math.isfinite(low):
        return low
    return high if math.isfinite(high) else 0.0
