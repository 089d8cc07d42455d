"""What slabs and blocks both need of space: the periodic box of each dimension, and distances to intervals."""

from __future__ import annotations

from typing import TypedDict

import torch
from torch import Tensor


class CutOptions(TypedDict, total=False):
    """How slabs and blocks are cut beyond the positions, the piece count and the halo depth.

    ``periodic_dims``: the dimensions that wrap around, within ``bounds`` (d (low, high) pairs, length units);
    ``weight``: (N,) each particle's work (:mod:`.work`), default one each (the particle count);
    ``halo_weight``: (N,) the work each particle costs a piece that holds it as halo (a halo of positions: its
    own work; of latents: one node), so that every cut weighs the halo it makes (:func:`.work.halo_cut`);
    None: halos are not weighed.
    """

    periodic_dims: tuple[int, ...]
    bounds: tuple[tuple[float, float], ...] | None
    weight: Tensor | None
    halo_weight: Tensor | None


def check_parts(parts: int) -> None:
    if parts < 1:
        raise ValueError(f"partitions must be at least 1, got {parts}")


def periodic_boxes(dim: int, options: CutOptions) -> list[tuple[float, float] | None]:
    """Per dimension, the (low, high) of its periodic box (length units), or None where it is not periodic."""
    box: list[tuple[float, float] | None] = [None] * dim
    bounds = options.get("bounds")
    for k in options.get("periodic_dims", ()):
        assert bounds is not None, "a periodic dimension needs the box bounds"
        box[k] = (float(bounds[k][0]), float(bounds[k][1]))
    return box


def distance_to_interval(x: Tensor, lower: Tensor, upper: Tensor) -> Tensor:
    """Distance of coordinates ``x`` to intervals ``[lower, upper]``, broadcast (0 inside).

    Shapes: (N, 1) coordinates and (P,) intervals give (N, P); (N, 1, d) and (P, d) give (N, P, d).
    """
    return torch.clamp(torch.maximum(lower - x, x - upper), min=0)
