"""No edges: every particle stands alone, for processors that mix information elsewhere.

A grid processor (``grid_cnn``) moves the particles' latents onto a grid and back;
its first, local update sums the edge latents at their receivers, which is the
only thing the edges are for. Without them a rollout step skips the neighbour
search and the edge MLP (on the general sand model: 15 % and about a quarter of
a step), and the grid alone carries what neighbours know of each other, as in
NeuralMPM. Message-passing processors over edges learn nothing with this builder.
"""

from __future__ import annotations

import torch
from torch import Tensor

from gns_framework.contracts import Graph, GraphBuilder


class NoEdgesGraphBuilder(GraphBuilder):
    """The empty graph of ``N`` particles: no senders, no receivers.

    Shapes: ``senders`` and ``receivers`` (0,), ``displacement`` (0, d).
    """

    name = "no_edges"

    def build(self, position: Tensor, batch: Tensor, num_examples: int) -> Graph:
        empty = torch.empty(0, dtype=torch.long, device=position.device)
        return Graph(empty, empty, position.new_zeros(0, position.shape[1]), position.shape[0], receivers_sorted=True)
