"""The fixed-radius search of :mod:`.cell_list` into buffers of fixed size, so the host never waits for the device.

:func:`.cell_list.radius_pairs` returns exactly the pairs, so its output size is data
and the host must wait for the device to learn it (two read-backs per search). Here
the pairs go into buffers of a fixed capacity instead: the first ``pairs`` rows are
the same pairs in the same order, the rest is padding, and what the search needed
(pairs, candidates, cells) stays on the device. A caller reads it now and then (every
few steps of a rollout) and searches again with larger buffers if a buffer was ever
too small; until then every step is the same operations on the same shapes, which a
CUDA graph can capture.

The grid is fixed in size too: cells of side >= R starting one cell below the
particles' lowest corner (found on the device each search, so the grid follows the
scene), with the last cell on each axis collecting every particle beyond the grid's
far end (clamping keeps two particles closer than R in the same or adjacent cells, so
no pair is lost, only the search slows), and a counting sort bins the particles (no
``torch.unique``).

Shapes: position (N, d), batch (N,) -> senders, receivers (E_cap,) int64; pairs,
candidates () int64; cells_needed (d,) int64.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache
from typing import NamedTuple

import torch
from torch import Tensor

from .cell_list import squared_distance


@dataclass(frozen=True)
class CellGrid:
    """``cells_per_axis`` cells of side ``cell`` per axis, from one cell below the particles' lowest corner.

    Cell 0 of each axis is empty margin (the lowest particle sits in cell 1); the last
    cell collects everything beyond the grid.
    """

    cells_per_axis: tuple[int, ...]
    cell: float

    @classmethod
    def for_extent(cls, extent: tuple[float, ...], radius: float, max_cells: int) -> CellGrid:
        """A grid whose inner cells cover ``extent`` (m per axis), cells >= R, at most about ``max_cells`` cells.

        Slightly larger cells than R keep every pair closer than R within adjacent cells
        despite rounding; a scene spread far relative to R gets larger cells (more
        candidates per particle) rather than a grid larger than its particles need.
        """
        cell = radius * (1 + 2**-20)
        dim = len(extent)
        cells = math.prod(_cells_covering(span, cell) for span in extent)
        if cells > max_cells:
            cell *= (cells / max_cells) ** (1 / dim)
        return cls(tuple(_cells_covering(span, cell) for span in extent), cell)

    @property
    def num_cells(self) -> int:
        return math.prod(self.cells_per_axis)

    def sizes(self, device: torch.device) -> Tensor:
        """(d,) int64 ``cells_per_axis`` on ``device``, made once: a captured step cannot copy it from the host."""
        return _sizes(self.cells_per_axis, device)

    def coordinates(self, position: Tensor, lower: Tensor) -> Tensor:
        """(N, d) int64 cell of each particle, counted from ``lower`` ((d,), one cell below the lowest particle)."""
        highest = self.sizes(position.device) - 1
        raw = torch.floor((position.detach().to(torch.float64) - lower) / self.cell)
        # Clamp in floating point first: a particle at 1e30 m must not overflow int64 (NaN goes to cell 0).
        raw = torch.nan_to_num(raw, nan=0.0).clamp(min=0.0, max=float(max(self.cells_per_axis)))
        return torch.minimum(raw.long(), highest)

    def linear(self, coordinates: Tensor) -> Tensor:
        """Row-major index of each cell (..., d) -> (...)."""
        index = coordinates[..., 0]
        for k, size in enumerate(self.cells_per_axis[1:], start=1):
            index = index * size + coordinates[..., k]
        return index


@cache
def _sizes(cells_per_axis: tuple[int, ...], device: torch.device) -> Tensor:
    return torch.tensor(cells_per_axis, device=device)


def _cells_covering(span: float, cell: float) -> int:
    """Cells along one axis: the margin below, those covering ``span``, one for the far end and beyond."""
    return math.floor(max(span, 0.0) / cell) + 1 + 2


class PaddedPairs(NamedTuple):
    """The pairs in fixed-size buffers and what the search needed, all on the device.

    Attributes:
        senders, receivers: (E_cap,) int64; rows from ``pairs`` on are padding, the pair
            (``pad``, ``pad``), after every real pair so that receivers stay sorted.
        pairs: () int64 pairs found; the first ``pairs`` rows hold them when no buffer was short.
        candidates: () int64 candidate pairs examined (the candidate buffer needed this many rows).
        cells_needed: (d,) int64 cells per axis that would cover the particles without the last
            cell's overflow (the grid is short, and the search slower, where it exceeds the grid).
    """

    senders: Tensor
    receivers: Tensor
    pairs: Tensor
    candidates: Tensor
    cells_needed: Tensor

    def overflowed(self, candidate_capacity: int, edge_capacity: int) -> Tensor:
        """() bool on the device: a buffer was too small, so the pairs are incomplete."""
        return (self.candidates > candidate_capacity) | (self.pairs > edge_capacity)


def padded_radius_pairs(
    position: Tensor,
    batch: Tensor,
    num_examples: int,
    radius: float,
    grid: CellGrid,
    candidate_capacity: int,
    edge_capacity: int,
    pad: int | None = None,
) -> PaddedPairs:
    """Every ordered pair (sender j, receiver i) of one example with |p_j - p_i|^2 < R^2, in fixed-size buffers.

    The pairs, their order (by receiver, then sender) and the strict comparison against
    ``R*R`` in the positions' dtype are those of :func:`.cell_list.radius_pairs`. No
    operation here needs the host to learn a size from the device.

    Args:
        position: (N, d) positions; batch: (N,) int64 example of each particle, of ``num_examples``.
        grid: the cells' shape and side (:meth:`CellGrid.for_extent`).
        candidate_capacity: rows for the candidate pairs (every particle of the 3^d cells
            around each particle); edge_capacity: rows for the pairs kept.
        pad: the particle index padding rows hold (default N - 1; a builder passes N, a
            sink node that no real particle is).
    """
    n, dim = position.shape
    device = position.device
    pad = n - 1 if pad is None else pad
    zero = torch.zeros((), dtype=torch.long, device=device)
    if n == 0:
        padding = torch.full((edge_capacity,), pad, dtype=torch.long, device=device)
        return PaddedPairs(padding, padding.clone(), zero, zero.clone(), torch.zeros(dim, dtype=torch.long))
    cells = grid.num_cells
    detached = position.detach().to(torch.float64)
    finite = torch.isfinite(detached).all(1, keepdim=True)
    # Non-finite particles (a diverged rollout, a capacity class's padding) must not move the grid.
    lower = torch.where(finite, detached, math.inf).amin(0).nan_to_num(posinf=0.0) - grid.cell
    coordinates = grid.coordinates(position, lower)
    cells_needed = _cells_needed(detached, finite, lower, grid.cell)
    example = batch.to(device=device, dtype=torch.long)
    # A non-finite particle joins no pair (its distances are NaN): it goes to a bucket after every cell, which no
    # particle searches, and searches none itself; a batch padded with NaN rows (a capacity class) pays nothing.
    absent = num_examples * cells
    key = torch.where(finite[:, 0], example * cells + grid.linear(coordinates), absent)

    # Counting sort: particles per (example, cell), where each cell's run starts, particles in key order.
    counts = torch.zeros(absent + 1, dtype=torch.long, device=device)
    counts.index_add_(0, key, torch.ones_like(key))
    starts = torch.cumsum(counts, 0) - counts
    order = torch.sort(key, stable=True).indices

    # The 3^d cells around each particle, in row-major order; those beyond the grid hold no one.
    offsets = torch.cartesian_prod(*[torch.arange(-1, 2, device=device)] * dim).view(-1, dim)
    around = coordinates[:, None, :] + offsets[None]  # (N, 3^d, d)
    size = grid.sizes(device)
    inside = ((around >= 0) & (around < size)).all(-1) & finite
    around_key = example[:, None] * cells + grid.linear(around.clamp(min=0).minimum(size - 1))
    range_count = torch.where(inside, counts[around_key], 0).reshape(-1)  # (N * 3^d,)
    range_start = starts[around_key].reshape(-1)

    # Candidate slot k lies in the range (receiver, cell) whose cumulative count first passes k.
    range_end = torch.cumsum(range_count, 0)
    total = range_end[-1]
    slot = torch.arange(candidate_capacity, device=device)
    range_of = torch.searchsorted(range_end, slot, right=True).clamp(max=range_end.numel() - 1)
    within = slot - (range_end[range_of] - range_count[range_of])
    real = slot < total
    sender = order[(range_start[range_of] + within).clamp(min=0, max=n - 1)]
    receiver = range_of // offsets.shape[0]
    r2 = torch.full((), radius * radius, dtype=position.dtype, device=device)
    kept = real & (squared_distance(position[receiver], position[sender]) < r2)

    # Compaction without a boolean selection: each kept pair's row is the count of kept pairs before it.
    row = torch.cumsum(kept.long(), 0) - 1
    count = row[-1] + 1 if row.numel() else zero
    target = torch.where(kept & (row < edge_capacity), row, edge_capacity)  # row edge_capacity: discarded
    senders = torch.full((edge_capacity + 1,), pad, dtype=torch.long, device=device)
    receivers = torch.full((edge_capacity + 1,), pad, dtype=torch.long, device=device)
    senders.scatter_(0, target, sender)
    receivers.scatter_(0, target, receiver)
    senders, receivers = senders[:edge_capacity], receivers[:edge_capacity]

    # Candidates of one receiver come cell by cell: sort each receiver's senders, padding last.
    real_edge = torch.arange(edge_capacity, device=device) < count
    span = max(n, pad + 1)
    ordering = torch.where(real_edge, receivers * span + senders, span * span)
    by = torch.sort(ordering, stable=True).indices
    return PaddedPairs(senders[by], receivers[by], count, total, cells_needed)


def _cells_needed(position: Tensor, finite: Tensor, lower: Tensor, cell: float) -> Tensor:
    """(d,) int64 cells per axis that cover the finite positions from ``lower`` with both margin cells."""
    highest = torch.where(finite, position, lower).amax(0)
    span = ((highest - lower) / cell).clamp(max=2.0**40)
    return span.floor().long() + 2
