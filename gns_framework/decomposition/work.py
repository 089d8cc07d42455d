"""How much work each particle brings to the piece that owns it, and cuts that share that work evenly.

A learned step costs per edge (the edge block is most of it) plus a little per particle:
a piece of a dense pile with as many particles as a piece of loose spray has several times
its edges. So pieces are cut at quantiles of the work, each particle weighing one plus the
edges it receives (its neighbours within the connectivity radius, itself included), as the
model's own graph builder counts them; a builder without edges leaves every particle one.
"""

from __future__ import annotations

import torch
from torch import Tensor

from ..contracts import GraphBuilder


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
