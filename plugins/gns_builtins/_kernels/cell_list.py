"""Exact fixed-radius neighbour search on a cell list, in pure torch, O(N).

Particles are binned into cubic cells of side ~R; candidates come from the 3^d
cells around each particle, so the work per particle does not grow with N.
Cell coordinates are rank-compressed per dimension, so keys stay small however
far particles spread (no overflow on exploding rollouts).
"""

from __future__ import annotations

import torch
from torch import Tensor

from gns_framework.api import read_back

CANDIDATES_PER_CHUNK_CPU = 1 << 20
"""Bounds the memory of candidate pairs (each costs ~50 bytes across the work arrays).

Chunks of ~50 MB stay in the last-level cache: with 8M candidates per chunk the
per-particle search time grew 1.8x from 10k to 100k particles; with 1M it is flat.
"""

CANDIDATES_PER_CHUNK_ACCELERATOR = 1 << 25
"""On GPUs chunks only bound the work arrays (~1.6 GB): a 1M-particle 3D scene
(~130M candidates) takes 4 chunks, each one read-back of its kept-pair count."""


def candidates_per_chunk(device: torch.device) -> int:
    return CANDIDATES_PER_CHUNK_CPU if device.type == "cpu" else CANDIDATES_PER_CHUNK_ACCELERATOR


class DenseRanks:
    """Dense ranks of integer values (0 for the smallest, +1 at each new value), without ``torch.unique``.

    ``torch.unique`` waits for the device (its output size is data); a sort and a
    cumulative count of value changes give the same ranks with no read-back, and
    the number of distinct values stays a 0-d tensor on the device.

    Attributes:
        ranks: (N,) rank of each value, in the values' order.
        sorted_values: (N,) the values sorted.
        sorted_ranks: (N,) the rank of each sorted value.
        size: () number of distinct values, on the device.
    """

    def __init__(self, values: Tensor):
        self.sorted_values, order = torch.sort(values)
        changes = torch.zeros_like(self.sorted_values)
        changes[1:] = (self.sorted_values[1:] != self.sorted_values[:-1]).to(changes.dtype)
        self.sorted_ranks = torch.cumsum(changes, 0)
        self.ranks = torch.empty_like(self.sorted_ranks).scatter_(0, order, self.sorted_ranks)
        self.size = self.sorted_ranks[-1] + 1

    def rank_of(self, target: Tensor) -> tuple[Tensor, Tensor]:
        """Rank of each value of ``target`` and whether it occurs among the values (else the rank is meaningless)."""
        n = self.sorted_values.numel()
        position = torch.searchsorted(self.sorted_values, target)
        inside = position.clamp(max=n - 1)
        exists = (position < n) & (self.sorted_values[inside] == target)
        return self.sorted_ranks[inside], exists


def squared_distance(a: Tensor, b: Tensor) -> Tensor:
    """``sum_k (a_k - b_k)^2`` accumulated left to right in the inputs' dtype.

    The reference (nanoflann) sums in this order; ``torch.cdist``'s matmul path
    differs by up to ~3e-4 relative in float32 and would move pairs across the radius.
    """
    diff = a - b
    d2 = diff[:, 0] * diff[:, 0]
    for k in range(1, diff.shape[1]):
        d2 = d2 + diff[:, k] * diff[:, k]
    return d2


def radius_pairs(position: Tensor, batch: Tensor, radius: float) -> tuple[Tensor, Tensor]:
    """Every ordered pair (sender j, receiver i) of one example with |p_j - p_i|^2 < R^2.

    Self-pairs are included (their distance is 0). The comparison is strict and made
    against ``R*R`` rounded to the positions' dtype, as the reference does.

    Args:
        position: (N, d) positions.
        batch: (N,) int64 example index per particle; particles of different examples
            never connect.
        radius: connectivity radius R (> 0).

    Returns:
        senders, receivers: (E,) int64, sorted by receiver, then sender.

    The edge count is data: on GPUs the search reads back the candidate counts of
    its chunks (one read, two with several chunks) and, per chunk, waits for the
    pairs kept within R (a boolean selection); nothing else waits for the device.
    """
    n, dim = position.shape
    device = position.device
    empty = torch.empty(0, dtype=torch.long, device=device)
    if n == 0:
        return empty, empty
    pos64 = position.detach().to(torch.float64)
    # Slightly larger cells keep every pair closer than R within adjacent cells despite rounding.
    cell = torch.floor((pos64 - pos64.min(0).values) / (radius * (1 + 2**-20))).long()
    example = batch.to(device=device, dtype=torch.long)

    axes = [DenseRanks(example)] + [DenseRanks(cell[:, k].contiguous()) for k in range(dim)]
    ranks = [axis.ranks for axis in axes]
    # Keys combine ranks, not coordinates: they stay below the product of the distinct cells per axis.
    sizes = [axis.size for axis in axes]

    def combine(parts: list[Tensor]) -> Tensor:
        key = parts[0]
        for size, part in zip(sizes[1:], parts[1:], strict=True):
            key = key * size + part
        return key

    sorted_keys, order = torch.sort(combine(ranks), stable=True)

    # All 3^d neighbour cells at once (on a GPU each operation is a launch); row c: cell offsets - 1 per axis.
    offsets = torch.cartesian_prod(*[torch.arange(3, device=device)] * dim).view(-1, dim)
    key = ranks[0].expand(offsets.shape[0], n)
    exists = torch.ones(offsets.shape[0], n, dtype=torch.bool, device=device)
    for k in range(dim):
        shifted = cell[:, k] + torch.arange(-1, 2, device=device)[:, None]  # (3, N): the axis' three cells
        axis_ranks, axis_exists = axes[k + 1].rank_of(shifted.reshape(-1))
        key = key * sizes[k + 1] + axis_ranks.view(3, n)[offsets[:, k]]
        exists = exists & axis_exists.view(3, n)[offsets[:, k]]
    flat_key = key.reshape(-1)
    lo = torch.searchsorted(sorted_keys, flat_key, right=False)
    hi = torch.searchsorted(sorted_keys, flat_key, right=True)
    # (N, 3^d): each receiver's range of sorted particles in each neighbour cell.
    starts_t = lo.view(-1, n).T
    counts_t = torch.where(exists.reshape(-1), hi - lo, torch.zeros_like(lo)).view(-1, n).T

    # Filled on the device: torch.tensor(value, device=...) would copy it from the host on every call.
    r2 = torch.full((), radius * radius, dtype=position.dtype, device=device)
    per_receiver = counts_t.sum(1)
    bounds, totals = _chunk_bounds(per_receiver, candidates_per_chunk(device))
    senders_out, receivers_out = [], []
    for lo_i, hi_i, total in zip(bounds[:-1], bounds[1:], totals, strict=True):
        s, r = _expand(starts_t[lo_i:hi_i], counts_t[lo_i:hi_i], order, lo_i, total)
        # One wait for the kept count (nonzero), shared by both selections.
        kept = (squared_distance(position[r], position[s]) < r2).nonzero().squeeze(1)
        s, r = s[kept], r[kept]
        # Candidates of one receiver arrive cell by cell; sort them into sender order.
        perm = torch.argsort(r * n + s)
        senders_out.append(s[perm])
        receivers_out.append(r[perm])
    return torch.cat(senders_out), torch.cat(receivers_out)


def _chunk_bounds(per_receiver: Tensor, size: int) -> tuple[list[int], list[int]]:
    """Receiver indices splitting the candidate list into chunks of about ``size`` candidates, and each chunk's count.

    Reads back the total, and when it exceeds ``size`` the cuts with the cumulative
    counts there: two waits for the device per search at most.
    """
    n = per_receiver.numel()
    cumulative = torch.cumsum(per_receiver, 0)
    total = read_back(cumulative[-1])
    if total <= size:
        return [0, n], [total]
    marks = torch.arange(size, total, size, device=per_receiver.device)
    cuts = torch.searchsorted(cumulative, marks, right=True).clamp(max=n)
    ends = torch.cat([cuts, cuts.new_full((1,), n)])
    cuts, reached = read_back(torch.stack([ends, cumulative[(ends - 1).clamp(min=0)] * (ends > 0)]))
    bounds, totals, before = [0], [], 0
    for cut, done in zip(cuts, reached, strict=True):
        if bounds[-1] < cut:
            bounds.append(cut)
            totals.append(done - before)
            before = done
    return bounds, totals


def _expand(starts: Tensor, counts: Tensor, order: Tensor, first_receiver: int, total: int) -> tuple[Tensor, Tensor]:
    """Candidate (sender, receiver) pairs from per-(receiver, cell) ranges of the sorted particles.

    ``total`` is the number of candidates, ``counts.sum()``, known on the host.
    """
    rows, cells = counts.shape
    flat_counts = counts.reshape(-1)
    receiver_of_range = (
        torch.arange(rows, device=counts.device)[:, None].expand(rows, cells).reshape(-1) + first_receiver
    )
    receivers = receiver_of_range.repeat_interleave(flat_counts, output_size=total)
    range_start = (torch.cumsum(flat_counts, 0) - flat_counts).repeat_interleave(flat_counts, output_size=total)
    within = torch.arange(total, device=counts.device) - range_start
    senders = order[starts.reshape(-1).repeat_interleave(flat_counts, output_size=total) + within]
    return senders, receivers
