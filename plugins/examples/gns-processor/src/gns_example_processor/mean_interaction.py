"""An interaction network that averages the messages at each receiver instead of summing them.

One step, with node latents x (N, L) and edge latents e (E, L)::

    e'_k = LN(MLP_e([e_k, x_receiver(k), x_sender(k)]))
    m_i  = mean of e'_k over the edges k whose receiver is i
    x'_i = LN(MLP_n([x_i, m_i]))
    x <- x + x',  e <- e + e'

A sum grows with the number of neighbours, so a model trained at one particle
spacing sees larger aggregates at a denser one; a mean does not.
"""

from __future__ import annotations

import torch
from pydantic import Field
from torch import Tensor, nn

from gns_framework.api import NormedMLP
from gns_framework.contracts import ComponentParams, Graph, ModelSizes, Processor


class MeanInteractionStep(nn.Module):
    """One step. Shapes: x (N, L), e (E, L), inverse_degree (N, 1) -> x (N, L), e (E, L)."""

    def __init__(self, sizes: ModelSizes):
        super().__init__()
        latent, hidden, layers = sizes.latent, sizes.mlp_hidden, sizes.mlp_hidden_layers
        self.edge_mlp = NormedMLP(3 * latent, hidden, layers, latent)
        self.node_mlp = NormedMLP(2 * latent, hidden, layers, latent)

    def forward(self, x: Tensor, e: Tensor, graph: Graph, inverse_degree: Tensor) -> tuple[Tensor, Tensor]:
        update = self.edge_mlp(torch.cat([e, x[graph.receivers], x[graph.senders]], dim=-1))
        # Summed in the update's own dtype: under autocast it is lower than the latents'.
        total = update.new_zeros(graph.num_nodes, update.shape[1]).index_add_(0, graph.receivers, update)
        x_update = self.node_mlp(torch.cat([x, total * inverse_degree], dim=-1))
        return x + x_update, e + update


class MeanInteractionNetwork(Processor):
    """M unshared mean-aggregation steps with residuals; a drop-in for ``interaction_network``."""

    name = "mean_interaction_network"

    class Params(ComponentParams):
        message_passing_steps: int = Field(10, ge=1, description="M, number of unshared steps")

    def __init__(self, params: Params, sizes: ModelSizes):
        super().__init__(params, sizes)
        self.steps = nn.ModuleList(MeanInteractionStep(sizes) for _ in range(params.message_passing_steps))

    def forward(self, node_latent: Tensor, edge_latent: Tensor, graph: Graph) -> tuple[Tensor, Tensor]:
        # Every step averages over the same edges: count each node's incoming ones once. The built-in
        # graph builders connect each particle to itself, so no count is 0; the clamp is for those that do not.
        ones = node_latent.new_ones(graph.num_edges, 1)
        degree = node_latent.new_zeros(graph.num_nodes, 1).index_add_(0, graph.receivers, ones)
        inverse_degree = 1 / degree.clamp(min=1)
        for step in self.steps:
            node_latent, edge_latent = step(node_latent, edge_latent, graph, inverse_degree)
        return node_latent, edge_latent
