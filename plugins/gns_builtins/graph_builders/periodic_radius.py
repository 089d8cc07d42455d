"""The radius graph in a domain that wraps around: minimum-image neighbours."""

from __future__ import annotations

import itertools

import torch
from torch import Tensor

from gns_framework.api import PerDevice, PeriodicBox, RecipeError
from gns_framework.contracts import ComponentParams, Graph, GraphBuilder, ModelSetup

from .._kernels.cell_list import radius_pairs


class PeriodicRadiusGraphBuilder(GraphBuilder):
    """Edges between particles closer than R (strict) under the minimum-image convention.

    Positions are wrapped into the box along the scene's periodic dimensions;
    particles within R of a periodic face get ghost images shifted by +-L (and
    their combinations at edges and corners), and the exact cell list of ``radius``
    runs on particles plus ghosts. Only real particles receive; an edge from a
    ghost is an edge from its particle, with the displacement to the image. Every
    box length must exceed 2R, so each pair is connected through at most one image.

    Without periodic dimensions this is the ``radius`` graph. Edges are sorted by
    (receiver, sender); ``Graph.displacement`` is the minimum image.
    """

    name = "periodic_radius"
    joins_within_radius = True
    supports_periodic = True

    def __init__(self, params: ComponentParams, setup: ModelSetup):
        super().__init__(params, setup)
        self.box = PeriodicBox(setup)
        self._shifts = PerDevice(self._make_shifts)
        short = [
            (k, float(length))
            for k, length in zip(self.box.dims, self.box.length, strict=True)
            if not length > 2 * setup.connectivity_radius
        ]
        if short:
            raise RecipeError(
                None,
                [
                    (
                        "model.connectivity_radius",
                        f"the periodic box lengths {short} (dimension, length) must exceed 2R = "
                        f"{2 * setup.connectivity_radius} for minimum-image neighbours",
                    )
                ],
            )

    def build(self, position: Tensor, batch: Tensor, num_examples: int) -> Graph:
        n = position.shape[0]
        if not self.box.active:
            senders, receivers = radius_pairs(position, batch, self.setup.connectivity_radius)
            return Graph(senders, receivers, position[senders] - position[receivers], n, receivers_sorted=True)
        position = self.box.wrap(position)
        ghost_position, ghost_of, ghost_batch = self._ghosts(position, batch)
        all_position = torch.cat([position, ghost_position])
        all_batch = torch.cat([batch, ghost_batch])
        senders, receivers = radius_pairs(all_position, all_batch, self.setup.connectivity_radius)
        real = receivers < n
        senders, receivers = senders[real], receivers[real]
        displacement = all_position[senders] - all_position[receivers]
        owner = torch.cat([torch.arange(n, device=position.device), ghost_of])
        senders = owner[senders]
        order = torch.argsort(receivers * n + senders)
        return Graph(senders[order], receivers[order], displacement[order], n, receivers_sorted=True)

    def _ghosts(self, position: Tensor, batch: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """Images of the particles within R of a periodic face, shifted across it.

        Which particles are near a face is data: selecting them reads a count back
        from the device, as the cell list's edge count does.
        """
        radius = self.setup.connectivity_radius
        dims, lower, length = self.box.constants(position)
        index = torch.arange(position.shape[0], device=position.device)
        positions, owners = [], []
        for shift in self._shifts(position):
            moved = position.index_add(1, dims, (shift * length).expand(position.shape[0], -1))
            inside = (moved.index_select(1, dims) > lower - radius) & (
                moved.index_select(1, dims) < lower + length + radius
            )
            near = inside.all(1)
            positions.append(moved[near])
            owners.append(index[near])
        return torch.cat(positions), torch.cat(owners), batch[torch.cat(owners)]

    def _make_shifts(self, like: Tensor) -> Tensor:
        """(3^p - 1, p) every combination of -1, 0, +1 box lengths along the periodic dimensions but none."""
        combos = [s for s in itertools.product((-1, 0, 1), repeat=len(self.box.dims)) if any(s)]
        return torch.tensor(combos, dtype=like.dtype, device=like.device)
