"""The fixed-radius search of :mod:`.cell_list` into buffers of fixed size, so the host never waits for the device.

:func:`.cell_list.radius_pairs` returns exactly the pairs, so its output size is data
and the host must wait for the device to learn it (two read-backs per search). Here
the pairs go into buffers of a fixed capacity instead: the first ``count`` rows are
the same pairs in the same order, the rest is padding, and ``count`` and an overflow
flag stay on the device. A caller reads the flag now and then (every few steps of a
rollout) and searches again with larger buffers if it was ever set; until then every
step is the same operations on the same shapes, which a CUDA graph can capture.

The grid is fixed too: cells of side ~R over the scene's bounds, with one margin cell
on each side that collects every particle beyond the walls (clamping keeps two
particles closer than R in the same or adjacent cells, so no pair is lost), and a
counting sort bins the particles (no ``torch.unique``).

Shapes: position (N, d), batch (N,) -> senders, receivers (E_cap,) int64; count ()
int64; overflow () bool.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from .cell_list import squared_distance


@dataclass(frozen=True)
class CellGrid:
    """Cells of side ``cell`` over ``bounds`` ((d, 2) lower and upper wall per axis), plus a margin cell each side."""

    bounds: tuple[tuple[float, float], ...]
    cell: float

    @classmethod
    def for_radius(cls, bounds: tuple[tuple[float, float], ...], radius: float) -> CellGrid:
        # Slightly larger cells keep every pair closer than R within adjacent cells despite rounding.
        return cls(tuple((float(lo), float(hi)) for lo, hi in bounds), radius * (1 + 2**-20))

    @property
    def cells_per_axis(self) -> tuple[int, ...]:
        """Inner cells covering [lo, hi] on each axis, plus the two margin cells."""
        return tuple(math.floor((hi - lo) / self.cell) + 1 + 2 for lo, hi in self.bounds)

    @property
    def num_cells(self) -> int:
        return math.prod(self.cells_per_axis)

    def coordinates(self, position: Tensor) -> Tensor:
        """(N, d) int64 cell of each particle, clamped into the margin cells beyond the walls."""
        lower = torch.tensor([lo for lo, _ in self.bounds], dtype=torch.float64, device=position.device)
        highest = torch.tensor(self.cells_per_axis, device=position.device) - 1
        raw = torch.floor((position.detach().to(torch.float64) - lower) / self.cell)
        # Clamp in floating point first: a particle at 1e30 m must not overflow int64.
        return torch.minimum(raw.clamp(min=-1.0, max=float(max(self.cells_per_axis))).long() + 1, highest)

    def linear(self, coordinates: Tensor) -> Tensor:
        """Row-major index of each cell (..., d) -> (...)."""
        index = coordinates[..., 0]
        for k, size in enumerate(self.cells_per_axis[1:], start=1):
            index = index * size + coordinates[..., k]
        return index


def padded_radius_pairs(
    position: Tensor,
    batch: Tensor,
    num_examples: int,
    radius: float,
    grid: CellGrid,
    candidate_capacity: int,
    edge_capacity: int,
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Every ordered pair (sender j, receiver i) of one example with |p_j - p_i|^2 < R^2, in fixed-size buffers.

    The pairs, their order (by receiver, then sender) and the strict comparison against
    ``R*R`` in the positions' dtype are those of :func:`.cell_list.radius_pairs`. No
    operation here needs the host to learn a size from the device.

    Args:
        position: (N, d) positions; batch: (N,) int64 example of each particle, of ``num_examples``.
        grid: the cells (:meth:`CellGrid.for_radius` of the scene's bounds).
        candidate_capacity: rows for the candidate pairs (every particle of the 3^d cells
            around each particle); edge_capacity: rows for the pairs kept.

    Returns:
        senders, receivers: (edge_capacity,) int64; rows from ``count`` on are padding,
        a self-pair of the last particle (N - 1, N - 1) so that receivers stay sorted;
        count: () int64 pairs found (the first ``count`` rows, when no overflow);
        overflow: () bool, True when a buffer was too small: the pairs are then
        incomplete and the search must run again with larger capacities.
    """
    n, dim = position.shape
    device = position.device
    if n == 0:
        empty = torch.zeros(edge_capacity, dtype=torch.long, device=device)
        return empty, empty.clone(), torch.zeros((), dtype=torch.long, device=device), torch.zeros((), dtype=torch.bool)
    cells = grid.num_cells
    coordinates = grid.coordinates(position)
    example = batch.to(device=device, dtype=torch.long)
    key = example * cells + grid.linear(coordinates)

    # Counting sort: particles per (example, cell), where each cell's run starts, particles in key order.
    counts = torch.zeros(num_examples * cells, dtype=torch.long, device=device)
    counts.index_add_(0, key, torch.ones_like(key))
    starts = torch.cumsum(counts, 0) - counts
    order = torch.sort(key, stable=True).indices

    # The 3^d cells around each particle, in row-major order; those beyond the grid hold no one.
    offsets = torch.cartesian_prod(*[torch.arange(-1, 2, device=device)] * dim).view(-1, dim)
    around = coordinates[:, None, :] + offsets[None]  # (N, 3^d, d)
    size = torch.tensor(grid.cells_per_axis, device=device)
    inside = ((around >= 0) & (around < size)).all(-1)
    around_key = example[:, None] * cells + grid.linear(around.clamp(min=0).minimum(size - 1))
    range_count = torch.where(inside, counts[around_key], 0).reshape(-1)  # (N * 3^d,)
    range_start = starts[around_key].reshape(-1)

    # Candidate slot k lies in the range (receiver, cell) whose cumulative count first passes k.
    range_end = torch.cumsum(range_count, 0)
    total = range_end[-1] if range_end.numel() else torch.zeros((), dtype=torch.long, device=device)
    slot = torch.arange(candidate_capacity, device=device)
    range_of = torch.searchsorted(range_end, slot, right=True).clamp(max=max(range_end.numel() - 1, 0))
    within = slot - (range_end[range_of] - range_count[range_of])
    real = slot < total
    sender = order[(range_start[range_of] + within).clamp(min=0, max=n - 1)]
    receiver = range_of // offsets.shape[0]
    r2 = torch.full((), radius * radius, dtype=position.dtype, device=device)
    kept = real & (squared_distance(position[receiver], position[sender]) < r2)

    # Compaction without a boolean selection: each kept pair's row is the count of kept pairs before it.
    row = torch.cumsum(kept.long(), 0) - 1
    count = row[-1] + 1 if row.numel() else torch.zeros((), dtype=torch.long, device=device)
    target = torch.where(kept & (row < edge_capacity), row, edge_capacity)  # row edge_capacity: discarded
    last = n - 1
    senders = torch.full((edge_capacity + 1,), last, dtype=torch.long, device=device)
    receivers = torch.full((edge_capacity + 1,), last, dtype=torch.long, device=device)
    senders.scatter_(0, target, sender)
    receivers.scatter_(0, target, receiver)
    senders, receivers = senders[:edge_capacity], receivers[:edge_capacity]

    # Candidates of one receiver come cell by cell: sort each receiver's senders, padding last.
    real_edge = torch.arange(edge_capacity, device=device) < count
    ordering = torch.where(real_edge, receivers * n + senders, n * n)
    by = torch.sort(ordering, stable=True).indices
    overflow = (total > candidate_capacity) | (count > edge_capacity)
    return senders[by], receivers[by], count, overflow
