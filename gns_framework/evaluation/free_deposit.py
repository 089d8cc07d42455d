"""Whether a granular deposit is free: its extent set by the flow rather than by the box.

A deposit that ends against both side walls spans the box whatever the flow did, so an extent error of 0 there says
nothing of a model; where the true deposit stops short of a wall on either side, a front the flow placed sets the
extent and its error is the model's. Reports give the extent errors of free deposits apart (issue 46: their median
within 8 %).

A front is at a wall when it ends within ``AT_WALL`` particle spacings of it, the tolerance the deposit warning's
fronts use (:mod:`gns_framework.model.deposit_signals`), the spacing measured on the sand's starting positions.

Shapes: B rollouts, N particles, d spatial dimensions; L is the dataset's length unit.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from ..data.particle_spacing import particle_spacing
from ..model.deposit_signals import AT_WALL


def wall_gaps(position: Tensor, weight: Tensor, bounds: Sequence[Sequence[float]], axis: int = 0) -> Tensor:
    """(B, N, d) positions -> (B, 2) distance from the lower wall along ``axis`` to the nearest weighted particle and
    from the farthest one to the upper wall, L (inf for a rollout with no weighted particle)."""
    along = position[..., axis]
    low = torch.where(weight, along, torch.inf).amin(-1) - float(bounds[axis][0])
    high = float(bounds[axis][1]) - torch.where(weight, along, -torch.inf).amax(-1)
    return torch.stack([low, high], dim=-1)


def free_deposits(
    final: Tensor, start: Tensor, weight: Tensor, bounds: Sequence[Sequence[float]], axis: int = 0
) -> Tensor:
    """(B,) True where the deposit ``final`` (B, N, d) ends more than ``AT_WALL`` particle spacings (of ``start``,
    (B, N, d)) from either wall along ``axis``; False where it reaches both. ``weight`` (B, N) marks the sand."""
    gaps = wall_gaps(final, weight, bounds, axis)
    h = torch.tensor(
        [particle_spacing(s[w].cpu().numpy()) if int(w.sum()) > 1 else 0.0 for s, w in zip(start, weight, strict=True)],
        dtype=gaps.dtype,
        device=gaps.device,
    )
    return (gaps > AT_WALL * h[:, None]).any(-1)
