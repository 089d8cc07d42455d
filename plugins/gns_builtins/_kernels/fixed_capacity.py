"""Radius searches into buffers sized once per scene and grown only when a check finds them short.

:func:`.padded_cell_list.padded_radius_pairs` needs its buffers' sizes (candidate pairs,
kept pairs, grid cells) before it runs. :class:`FixedCapacityRadius` learns them on the
first search of a scene (two read-backs), gives each ``growth`` times what it found,
and from then on searches without waiting for the device: what each search needed is
folded into a running maximum on the device, which :meth:`FixedCapacityRadius.overflowed`
reads (one read-back) when the caller asks, every few steps of a rollout.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from gns_framework.api import read_back

from .padded_cell_list import CellGrid, PaddedPairs, padded_radius_pairs

CELLS_PER_PARTICLE = 4
"""The grids of a batch's examples hold at most about this many cells per particle together: a scene spread far
relative to R gets cells larger than R (more candidates each) rather than counts larger than its particles."""


class FixedCapacityRadius:
    """The pairs closer than R of consecutive frames of one scene, in buffers of fixed size.

    Args:
        radius: connectivity radius R (> 0).
        growth: each buffer holds this many times the most its scene has needed (>= 1).

    ``sizings`` counts the times the buffers were sized (a new scene, or an overflow), for tests and benchmarks.
    """

    def __init__(self, radius: float, growth: float):
        self.radius, self.growth = radius, growth
        self.sizings = 0
        self.sized_for: tuple | None = None
        self.max_cells = 0
        self.grid: CellGrid | None = None
        self.candidate_capacity = self.edge_capacity = 0
        self.needed: Tensor | None = None

    def pairs(self, position: Tensor, batch: Tensor, num_examples: int, check_now: bool) -> tuple[Tensor, Tensor]:
        """Senders and receivers (E_cap,) int64: the pairs as ``radius_pairs`` gives them, then padding (N, N).

        ``check_now``: read back at once whether the buffers sufficed, and search again if not;
        otherwise the caller calls :meth:`overflowed` later and redoes what it built since.
        """
        scene = (position.shape, position.device, num_examples)
        if scene != self.sized_for:
            self._size(position, batch, num_examples)
            self.sized_for = scene
        found = self._search(position, batch, num_examples)
        if check_now:
            while self.overflowed():
                found = self._search(position, batch, num_examples)
        return found.senders, found.receivers

    def overflowed(self) -> bool:
        """Whether a search since the last call had a buffer too small (its pairs were incomplete).

        Reads the device once. Every buffer short of ``growth`` times what was needed
        is grown (the grid too, which only slows the search when short); the caller
        redoes the steps since its last call.
        """
        if self.needed is None:
            return False
        count, candidates, *cells = read_back(self.needed)
        self.needed.zero_()
        assert self.grid is not None  # sized with needed
        short = count > self.edge_capacity or candidates > self.candidate_capacity
        if short:
            # With too few candidate rows the pairs were counted among those examined only: scale up.
            count = count * candidates / max(min(candidates, self.candidate_capacity), 1)
            self.candidate_capacity = max(self.candidate_capacity, math.ceil(self.growth * candidates))
            self.edge_capacity = max(self.edge_capacity, math.ceil(self.growth * count))
            self.sizings += 1
        if any(need > have for need, have in zip(cells, self.grid.cells_per_axis, strict=True)):
            self.grid = self._grid(cells)
        return short

    def _search(self, position: Tensor, batch: Tensor, num_examples: int) -> PaddedPairs:
        assert self.grid is not None
        n = position.shape[0]
        found = padded_radius_pairs(
            position, batch, num_examples, self.radius, self.grid, self.candidate_capacity, self.edge_capacity, pad=n
        )
        needs = torch.cat([torch.stack([found.pairs, found.candidates]), found.cells_needed.to(found.pairs.device)])
        if self.needed is None:
            self.needed = needs
        else:  # in place: a captured step's replays keep adding to the same tensor
            torch.maximum(self.needed, needs, out=self.needed)
        return found

    def _size(self, position: Tensor, batch: Tensor, num_examples: int) -> None:
        """The buffers for a new scene: its extent, then its candidates, then its pairs (three read-backs)."""
        # Every example has its own copy of the grid's counts: the cap is on all of them together.
        self.max_cells = max(CELLS_PER_PARTICLE * position.shape[0] // num_examples, 3 ** position.shape[1])
        finite = position.detach()[torch.isfinite(position.detach()).all(1)]
        extent = read_back(finite.amax(0) - finite.amin(0)) if len(finite) else [0.0] * position.shape[1]
        self.grid = CellGrid.for_extent(tuple(extent), self.radius, self.max_cells)
        self.candidate_capacity = self.edge_capacity = 0
        self.needed = None
        for _ in range(2):  # the candidates' count is exact with no buffer; the pairs' once candidates fit
            found = self._search(position, batch, num_examples)
            candidates, count = read_back(torch.stack([found.candidates, found.pairs]))
            self.candidate_capacity = math.ceil(self.growth * candidates)
            self.edge_capacity = math.ceil(self.growth * count)
        self.needed = None
        self.sizings += 1

    def _grid(self, cells: list[int]) -> CellGrid:
        """A grid ``growth`` times the span that ``cells`` cells of the current grid cover."""
        assert self.grid is not None
        extent = tuple((need - 2) * self.grid.cell * self.growth for need in cells)
        return CellGrid.for_extent(extent, self.radius, self.max_cells)
