"""E(n)-equivariant processor after EGNN (Satorras, Hoogeboom and Welling 2021).

Each step, with node latents h, edge latents e and relative positions
``r_ij = x_j - x_i`` of sender j and receiver i (in units of R)::

    m_ij  = LN(MLP_e([e_ij, h_i, h_j, |r_ij|^2]))           invariant message
    x_i  <- x_i - mean_j( r_ij * tanh(MLP_x(m_ij)) )         equivariant position update
    h_i  <- h_i + LN(MLP_h([h_i, sum_j m_ij]))
    e_ij <- e_ij + m_ij

Positions enter only through ``|r_ij|^2``, and move only along ``r_ij``, so
rotating, reflecting or translating the input positions leaves h and e unchanged
and moves the positions with them. The positions start at the graph's
displacements and are updated on the way, so later steps see a learned geometry.

The processor is invariant; a whole model is equivariant only if its features
are too (the reference's velocity, wall and displacement features are not).
"""

from __future__ import annotations

import torch
from pydantic import Field
from torch import Tensor, nn

from gns_framework.api import MLP, NormedMLP
from gns_framework.contracts import ComponentParams, Graph, ModelSizes, Processor


class EquivariantStep(nn.Module):
    """One EGNN step. Shapes: h (N, L), e (E, L), offset (N, d); r (E, d) relative positions.

    The last step of a stack moves no positions (nothing would read them), so it has no ``position_mlp``.
    """

    def __init__(self, latent: int, hidden: int, hidden_layers: int, moves_positions: bool):
        super().__init__()
        self.message_mlp = NormedMLP(3 * latent + 1, hidden, hidden_layers, latent)
        self.position_mlp = MLP(latent, hidden, hidden_layers, 1) if moves_positions else None
        self.node_mlp = NormedMLP(2 * latent, hidden, hidden_layers, latent)

    def forward(
        self, h: Tensor, e: Tensor, offset: Tensor, relative: Tensor, senders: Tensor, receivers: Tensor, degree: Tensor
    ) -> tuple[Tensor, Tensor, Tensor]:
        r = relative + offset[senders] - offset[receivers]
        distance2 = (r * r).sum(-1, keepdim=True)
        message = self.message_mlp(torch.cat([e, h[receivers], h[senders], distance2], dim=-1))
        if self.position_mlp is not None:
            # tanh bounds each move to one edge length, which keeps deep stacks stable.
            pull = r * torch.tanh(self.position_mlp(message))
            offset = offset - torch.zeros_like(offset).index_add_(0, receivers, pull) / degree
        aggregate = torch.zeros_like(h).index_add_(0, receivers, message)
        h = h + self.node_mlp(torch.cat([h, aggregate], dim=-1))
        return h, e + message, offset


class EquivariantProcessor(Processor):
    """M unshared EGNN steps on the latent graph, using relative positions ``Graph.displacement / R``."""

    name = "egnn"
    hops_param = "message_passing_steps"

    class Params(ComponentParams):
        message_passing_steps: int = Field(10, ge=1, description="M, number of unshared steps")

    def __init__(self, params: Params, sizes: ModelSizes):
        super().__init__(params, sizes)
        self.connectivity_radius = sizes.connectivity_radius
        self.steps = nn.ModuleList(
            EquivariantStep(
                sizes.latent, sizes.mlp_hidden, sizes.mlp_hidden_layers, i < params.message_passing_steps - 1
            )
            for i in range(params.message_passing_steps)
        )

    def forward(self, node_latent: Tensor, edge_latent: Tensor, graph: Graph) -> tuple[Tensor, Tensor]:
        relative = graph.displacement / self.connectivity_radius
        offset = relative.new_zeros(graph.num_nodes, relative.shape[1])
        degree = torch.bincount(graph.receivers, minlength=graph.num_nodes).clamp(min=1)[:, None].to(relative)
        for step in self.steps:
            node_latent, edge_latent, offset = step(
                node_latent, edge_latent, offset, relative, graph.senders, graph.receivers, degree
            )
        return node_latent, edge_latent
