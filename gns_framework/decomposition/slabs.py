"""Slabs: the domain cut along one axis into P pieces of about equal work (or particle count), one per process.

Process r owns the particles whose coordinate along the axis lies in ``[cut_r, cut_{r+1})``
(the first slab open below, the last open above; in a periodic axis the box's faces close
them). A particle's next position depends on the particles within its receptive field, at
most ``depth`` away (connectivity radius times message-passing steps), so each process also
holds a halo: every particle of another slab closer than ``depth`` to its own along the axis
(through the periodic faces where the axis wraps around).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Unpack

import torch
from torch import Tensor

from .space import CutOptions, check_parts, distance_to_interval, periodic_boxes
from .work import halo_cut, quantile_cut


@dataclass(frozen=True)
class SlabPartition:
    """P slabs along ``axis``.

    Attributes:
        axis: the dimension cut.
        cuts: the P - 1 inner faces, ascending (dataset length units).
        depth: halo depth, the receptive field (length units).
        box: ``(lower, upper)`` of the axis when it wraps around (periodic), else None.
    """

    axis: int
    cuts: tuple[float, ...]
    depth: float
    box: tuple[float, float] | None = None

    @property
    def parts(self) -> int:
        return len(self.cuts) + 1

    def describe(self) -> str:
        return f"{self.parts} slabs along dimension {self.axis}"

    @classmethod
    def balanced(
        cls, position: Tensor, parts: int, depth: float, axis: int | None = None, **options: Unpack[CutOptions]
    ) -> SlabPartition:
        """Cuts at the quantiles of ``weight`` (N,; default: the particle count) of ``position`` (N, d) along ``axis``.

        ``axis`` defaults to the dimension in which the particles spread farthest (a
        periodic one counts its box length): the thinnest slabs relative to the halo.
        ``bounds`` (d pairs) gives the periodic box of ``periodic_dims``.
        """
        check_parts(parts)
        boxes = periodic_boxes(int(position.shape[1]), options)
        if axis is None:
            spread = (position.max(0).values - position.min(0).values).tolist()
            spread = [s if b is None else b[1] - b[0] for s, b in zip(spread, boxes, strict=True)]
            axis = max(range(len(spread)), key=lambda k: spread[k])
        box = boxes[axis]
        coordinate = position[:, axis].to(torch.float64)
        weight, halo = options.get("weight"), options.get("halo_weight")
        if halo is not None:
            cuts = tuple(_halo_cuts(coordinate, weight, halo, depth, parts))
        else:
            cuts = tuple(quantile_cut(coordinate, weight, k, parts) for k in range(1, parts)) if len(coordinate) else ()
        return cls(axis=axis, cuts=cuts, depth=float(depth), box=box)

    def owner(self, position: Tensor) -> Tensor:
        """(N,) int64 slab of each position (N, d)."""
        cuts = torch.tensor(self.cuts, dtype=position.dtype, device=position.device)
        return torch.bucketize(position[:, self.axis].contiguous(), cuts, right=True)

    def halo_of(self, position: Tensor) -> Tensor:
        """(N, P) bool: row i, column r is True when particle i lies within ``depth`` of slab r but outside it."""
        x = position[:, self.axis].to(torch.float64)[:, None]
        inf = float("inf")
        lower = torch.tensor((-inf, *self.cuts), dtype=torch.float64, device=position.device)
        upper = torch.tensor((*self.cuts, inf), dtype=torch.float64, device=position.device)
        if self.box is not None:
            lower[0], upper[-1] = self.box
        distance = distance_to_interval(x, lower, upper)
        if self.box is not None:
            length = self.box[1] - self.box[0]
            # Through the periodic faces: the particle's images one box length away.
            distance = torch.minimum(distance, distance_to_interval(x + length, lower, upper))
            distance = torch.minimum(distance, distance_to_interval(x - length, lower, upper))
        near = distance <= self.depth
        near[torch.arange(position.shape[0], device=position.device), self.owner(position)] = False
        return near


def _halo_cuts(
    coordinate: Tensor, weight: Tensor | None, halo: Tensor, depth: float, parts: int, fallback: float = 0.0
) -> list[float]:
    """The ``parts - 1`` cuts of the particles at ``coordinate`` (n,) by bisection, each cut weighing the halo it
    makes (:func:`.work.halo_cut`); a side without particles takes its parent's cut, ``fallback``."""
    if parts == 1:
        return []
    if len(coordinate) == 0:
        return [fallback] * (parts - 1)
    below = parts // 2
    cut = halo_cut(coordinate, weight, halo, depth, below, parts)
    first = coordinate < cut
    mine, theirs = (None, None) if weight is None else (weight[first], weight[~first])
    lower = _halo_cuts(coordinate[first], mine, halo[first], depth, below, cut)
    return [*lower, cut, *_halo_cuts(coordinate[~first], theirs, halo[~first], depth, parts - below, cut)]
