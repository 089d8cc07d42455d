"""k-nearest-neighbour graph: each particle receives from its k closest particles."""

from __future__ import annotations

import torch
from pydantic import Field
from torch import Tensor

from gns_framework.contracts import ComponentParams, Graph, GraphBuilder

from .._kernels.cell_list import squared_distance

_PAIRS_PER_CHUNK = 1 << 22
"""Bounds the memory of the distance block of one chunk of receivers."""


class KnnGraphBuilder(GraphBuilder):
    """Every particle receives from its ``k`` nearest particles of the same example.

    The particle itself counts as its own nearest neighbour (a self-edge, as in the
    radius graph) when ``self_edges`` is true. Examples with fewer than ``k``
    candidates connect everything. Ties are broken by the lower sender index, so
    the graph is deterministic. Unlike the radius graph every particle has the same
    in-degree, whatever the density; with ``max_radius`` set, neighbours at or
    beyond it are dropped.

    Cost: O(n^2) distances per example of n particles, computed in chunks of
    receivers so memory stays bounded; meant for small and medium scenes.
    Edges are sorted by (receiver, sender).
    """

    name = "knn"

    class Params(ComponentParams):
        k: int = Field(16, ge=1, description="neighbours per receiving particle")
        self_edges: bool = Field(True, description="a particle is its own neighbour (counts towards k)")
        max_radius: float | None = Field(None, gt=0, description="drop neighbours at distance >= this (dataset units)")

    params: Params  # the validated Params above (the base class assigns it)

    def build(self, position: Tensor, batch: Tensor, num_examples: int) -> Graph:
        n = position.shape[0]
        senders_out, receivers_out = [], []
        counts = torch.bincount(batch, minlength=num_examples).tolist()
        start = 0
        for count in counts:
            if count:
                s, r = self._example_edges(position[start : start + count].detach())
                senders_out.append(s + start)
                receivers_out.append(r + start)
            start += count
        if not senders_out:
            empty = torch.empty(0, dtype=torch.long, device=position.device)
            return Graph(empty, empty, position.new_zeros(0, position.shape[1]), n, receivers_sorted=True)
        senders, receivers = torch.cat(senders_out), torch.cat(receivers_out)
        return Graph(senders, receivers, position[senders] - position[receivers], n, receivers_sorted=True)

    def _example_edges(self, position: Tensor) -> tuple[Tensor, Tensor]:
        n = position.shape[0]
        k = min(self.params.k, n if self.params.self_edges else n - 1)
        if k <= 0:
            empty = torch.empty(0, dtype=torch.long, device=position.device)
            return empty, empty
        rows = max(1, _PAIRS_PER_CHUNK // n)
        index = torch.arange(n, device=position.device)
        senders_out, receivers_out = [], []
        for lo in range(0, n, rows):
            receivers = index[lo : lo + rows]
            pair_r = receivers.repeat_interleave(n)
            pair_s = index.repeat(receivers.numel())
            d2 = squared_distance(position[pair_r], position[pair_s]).reshape(-1, n)
            if not self.params.self_edges:
                d2[torch.arange(receivers.numel()), receivers] = torch.inf
            # A stable sort keeps equal distances in sender order: ties go to the lower index.
            nearest_d2, nearest = torch.sort(d2, dim=1, stable=True)
            nearest_d2, nearest = nearest_d2[:, :k], nearest[:, :k]
            keep = torch.isfinite(nearest_d2)
            if self.params.max_radius is not None:
                keep &= nearest_d2 < self.params.max_radius**2
            senders = torch.sort(torch.where(keep, nearest, n), dim=1).values
            receivers = receivers[:, None].expand_as(senders)
            valid = senders < n
            senders_out.append(senders[valid])
            receivers_out.append(receivers[valid])
        return torch.cat(senders_out), torch.cat(receivers_out)
