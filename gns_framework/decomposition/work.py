"""How much work each particle brings to the piece that owns it, and cuts that share that work evenly.

A learned step costs per edge (the edge block is most of it) plus a little per particle:
a piece of a dense pile with as many particles as a piece of loose spray has several times
its edges. So pieces are cut at quantiles of the work, each particle weighing one plus the
edges it receives (its neighbours within the connectivity radius, itself included), as the
model's own graph builder counts them; a builder without edges leaves every particle one.

A piece also computes its halo: with a halo of positions each halo particle with its edges, with a halo of
latents a node each. A cut that weighs only the owned particles gives the pieces in a dense pile equal work
of their own and a halo as large again; so the rollout's cuts weigh the halo each cut makes too
(:func:`halo_cut`): beside a pile as wide as the halo is deep, the busiest piece's work falls by 0.61-0.88x
with a halo of positions (slabs and blocks, 4 and 8 pieces), and stays within 1 % with a halo of latents.

A re-cut during a rollout needs the whole scene's work but no process holds the whole scene:
each bins its own particles' work on a coarse grid over the scene's box (:func:`work_summary`),
one sum gives every process the same grid, and the pieces are cut at the quantiles of the
occupied cells' work, which balances the pieces to within one slice of cells (a cut cannot split one).
"""

from __future__ import annotations

import torch
from torch import Tensor

from ..contracts import GraphBuilder
from ..runtime.processes import Processes
from .exchange import objects_everywhere


def particle_work(builder: GraphBuilder, position: Tensor) -> Tensor:
    """(N,) float64 work of each particle at ``position`` (N, d): 1 + the edges it receives in ``builder``'s graph."""
    n = position.shape[0]
    graph = builder.build(position, torch.zeros(n, dtype=torch.long, device=position.device), 1)
    received = graph.receivers[graph.receivers < n]  # a fixed-size graph's padding joins a sink node past the particles
    return 1.0 + torch.bincount(received, minlength=n)[:n].to(torch.float64)


def quantile_cut(coordinate: Tensor, weight: Tensor | None, below: int, parts: int) -> float:
    """The coordinate below which lies ``below / parts`` of the total weight of particles at ``coordinate`` (n,).

    ``weight`` None weighs every particle alike (a cut by count): the particle ``(n below) // parts`` in
    coordinate order, as unit weights give too.
    """
    ordered, order = torch.sort(coordinate, stable=True)
    n = ordered.shape[0]
    if weight is None:
        return float(ordered[min(n - 1, (n * below) // parts)])
    cumulative = torch.cumsum(weight[order].to(torch.float64), 0)
    index = int(torch.searchsorted(cumulative, cumulative[-1] * below / parts, right=True))
    return float(ordered[min(index, n - 1)])


def halo_cut(coordinate: Tensor, weight: Tensor | None, halo: Tensor, depth: float, below: int, parts: int) -> float:
    """The coordinate that cuts the particles at ``coordinate`` (n,) into a side for ``below`` of ``parts`` processes
    and a side for the rest, each side's work being its particles' ``weight`` (default: one each) plus the ``halo``
    work (n,) of the particles within ``depth`` across the cut, which it computes too: the cut where the larger
    work per process is least (the first such, in coordinate order).

    A cut at a particle's coordinate puts it above the cut, as :func:`quantile_cut`'s does.
    """
    ordered, order = torch.sort(coordinate.to(torch.float64), stable=True)
    own = torch.ones_like(ordered) if weight is None else weight[order].to(torch.float64)
    zero = ordered.new_zeros(1)
    owned, halos = torch.cat([zero, own.cumsum(0)]), torch.cat([zero, halo[order].to(torch.float64).cumsum(0)])

    def rank(x: Tensor) -> Tensor:  # particles strictly below each x
        return torch.searchsorted(ordered, x, right=False)

    first = rank(ordered)  # each candidate cut: the particles below it
    lower, upper = owned[first], owned[-1] - owned[first]
    # The lower side computes the particles in [c, c + depth) as halo; the upper side those in [c - depth, c).
    lower = lower + halos[rank(ordered + depth)] - halos[first]
    upper = upper + halos[first] - halos[rank(ordered - depth)]
    worst = torch.maximum(lower / below, upper / (parts - below))
    return float(ordered[int(torch.argmin(worst))])


SUMMARY_CELLS = 1 << 21
"""Most cells in a work summary's grid (their work and particle counts: 32 MB of float64 to sum over the processes)."""


def work_summary(position: Tensor, work: Tensor, particles: int, processes: Processes) -> tuple[Tensor, Tensor, Tensor]:
    """The whole scene's work on a coarse grid, from this process's own particles at ``position`` (n, d) with
    ``work`` (n,): (M, d) float64 centres of the occupied cells, (M,) their summed work and (M,) their particle
    counts, the same on every process. The grid spans the scene's box (one small gather of each process's corners)
    with about ``SUMMARY_CELLS`` cells of equal shape (fewer for a scene of fewer particles than that), so a cut,
    which cannot split a slice of cells, balances the pieces to within one slice's work; one sum over the
    processes. ``particles``: the scene's particle count."""
    dim = position.shape[1]
    inf = torch.full((dim,), torch.inf, dtype=torch.float64)
    local = position.detach().to("cpu", torch.float64)
    lower = local.min(0).values if len(local) else inf
    upper = local.max(0).values if len(local) else -inf
    corners = objects_everywhere(processes, (lower, upper))
    lower = torch.stack([c[0] for c in corners]).min(0).values
    upper = torch.stack([c[1] for c in corners]).max(0).values
    per_axis = max(1, int(min(max(particles, 4096) * 64, SUMMARY_CELLS) ** (1.0 / dim)))
    size = torch.clamp((upper - lower) / per_axis, min=torch.finfo(torch.float64).tiny)
    index = torch.clamp(((local - lower) / size).floor().long(), 0, per_axis - 1)
    flat = torch.zeros(len(local), dtype=torch.long)
    for axis in range(dim):
        flat = flat * per_axis + index[:, axis]
    cells = per_axis**dim
    grid = torch.cat(
        [
            torch.bincount(flat, weights=work.detach().to("cpu", torch.float64), minlength=cells),
            torch.bincount(flat, minlength=cells).to(torch.float64),
        ]
    )
    grid = processes.sum(grid.to(position.device)).cpu()
    grid_work, grid_count = grid[:cells], grid[cells:]
    occupied = grid_count.nonzero()[:, 0]
    cell = torch.stack([(occupied // per_axis ** (dim - 1 - axis)) % per_axis for axis in range(dim)], dim=1)
    return lower + (cell.to(torch.float64) + 0.5) * size, grid_work[occupied], grid_count[occupied]
