"""The reference processor: M unshared interaction-network steps with residuals.

One step, with node latents x and edge latents e (Battaglia et al. 2016; the paper's Eq. in Sec. 2)::

    e'_k = LN(MLP_e([e_k, x_receiver(k), x_sender(k)]))
    a_i  = sum of e'_k over edges k whose receiver is i
    x'_i = LN(MLP_n([x_i, a_i]))
    x <- x + x',  e <- e + e'

Our concatenation order is DeepMind's ([edge, receiver, sender] and [node, aggregate]); geoelements
uses [receiver, sender, edge] and [aggregate, node]: its checkpoints import by reordering columns.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Literal, cast

import torch
from pydantic import Field
from torch import Tensor, nn

from gns_framework.api import NormedMLP
from gns_framework.contracts import ComponentParams, Graph, ModelSizes, Processor

from .._kernels.edge_block import edge_block, edge_order, node_table, table_rows

if TYPE_CHECKING:
    from collections.abc import Sequence

EdgeBlock = Literal["fused", "plain"]
"""How the edge update runs: ``plain`` is the paper's three lines in torch, the code to read; ``fused``
(default) runs it in cache-sized chunks with fused CPU loops and a hand-written backward (``_kernels/edge_block.py``),
on CUDA as Triton kernels (``triton_edge_block.py``): faster, less memory, equal within rounding (mirror tests)."""


class InteractionStep(nn.Module):
    """One message-passing step. Shapes: x (N, L), e (E, L), senders and receivers (E,) int64; ``order``: edge_order."""

    def __init__(self, latent: int, hidden: int, hidden_layers: int, edge_block: EdgeBlock = "fused"):
        super().__init__()
        self.latent = latent
        self.edge_block = edge_block
        self.edge_mlp = NormedMLP(3 * latent, hidden, hidden_layers, latent)
        self.node_mlp = NormedMLP(2 * latent, hidden, hidden_layers, latent)

    def forward(self, x: Tensor, e: Tensor, senders: Tensor, receivers: Tensor, order=None) -> tuple[Tensor, Tensor]:
        if (
            self.edge_block == "fused"
        ):  # the next two lines as one chunked pass (or Triton kernel), equal within rounding
            edge_latent, aggregate = self._edge_update_and_aggregate(x, e, senders, receivers, order)
        else:
            # The edge update: each edge sees its own latent and the two particles it joins.
            edge_update = self.edge_mlp(torch.cat([e, x[receivers], x[senders]], dim=-1))
            # Aggregation: every particle sums the messages of the edges it receives.
            aggregate = x.new_zeros(x.shape).index_add(0, receivers, edge_update.to(x.dtype))
            edge_latent = e + edge_update
        # The node update from the particle's latent and its aggregate; residuals on both.
        node_update = self.node_mlp(torch.cat([x, aggregate], dim=-1))
        return x + node_update, edge_latent

    def _edge_update_and_aggregate(self, x: Tensor, e: Tensor, senders: Tensor, receivers: Tensor, order):
        """``(e + edge update, aggregate at receivers)`` in one chunked, fused pass (``_kernels/edge_block.py``)."""
        mlp = self.edge_mlp.mlp
        linears = cast("Sequence[nn.Linear]", mlp.linears)  # layers.MLP: a ModuleList of nn.Linear
        first = linears[0]
        # The first edge layer is linear in [e, x_r, x_s]: project the N nodes once and
        # gather, instead of multiplying E concatenated rows (same result, ~40% fewer FLOPs).
        table = node_table(x, first.weight, first.bias)
        rows = table_rows(senders, receivers, x.shape[0])
        weights = [first.weight[:, : self.latent]] + [linear.weight for linear in linears[1:]]
        biases: list[Tensor] = [linear.bias for linear in linears[1:]]
        return edge_block(e, table, rows, receivers, weights, biases, self.edge_mlp.norm, order=order)


class InteractionNetwork(Processor):
    """M interaction-network steps with separate weights (the paper's default, M = 10)."""

    name = "interaction_network"
    node_module_names = ("steps.*.node_mlp",)
    hops_param = "message_passing_steps"
    exchanges_latents = True

    class Params(ComponentParams):
        message_passing_steps: int = Field(10, ge=1, description="M, number of message-passing steps")
        edge_block: EdgeBlock = Field(
            "fused", description="fused (chunked, fast) or plain (the paper's lines); equal results"
        )

    def __init__(self, params: Params, sizes: ModelSizes):
        super().__init__(params, sizes)
        self.steps = nn.ModuleList(
            InteractionStep(sizes.latent, sizes.mlp_hidden, sizes.mlp_hidden_layers, params.edge_block)
            for _ in range(params.message_passing_steps)
        )

    def forward(self, node_latent: Tensor, edge_latent: Tensor, graph: Graph) -> tuple[Tensor, Tensor]:
        first = cast("InteractionStep", self.steps[0])
        order = edge_order(first, edge_latent, graph) if first.edge_block == "fused" else None
        for k, step in enumerate(self.steps):
            if k and graph.exchange is not None:  # a domain-decomposed step: the halo's latents from their owners
                node_latent = graph.exchange(node_latent)
            node_latent, edge_latent = step(node_latent, edge_latent, graph.senders, graph.receivers, order)
        return node_latent, edge_latent
