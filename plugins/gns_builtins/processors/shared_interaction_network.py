"""One interaction-network step applied M times with the same weights."""

from __future__ import annotations

from pydantic import Field
from torch import Tensor

from gns_framework.contracts import ComponentParams, Graph, ModelSizes, Processor

from .._kernels.edge_block import edge_order
from .interaction_network import EdgeBlock, InteractionStep


class SharedInteractionNetwork(Processor):
    """The reference step (see ``interaction_network``) repeated M times, weights shared.

    M times fewer processor parameters than the unshared network for the same
    receptive field (M hops); the cost per step is unchanged.
    """

    name = "shared_interaction_network"
    hops_param = "message_passing_steps"
    exchanges_latents = True

    class Params(ComponentParams):
        message_passing_steps: int = Field(10, ge=1, description="M, times the one step is applied")
        edge_block: EdgeBlock = Field(
            "fused", description="fused (chunked, fast) or plain (the paper's lines); equal results"
        )

    params: Params  # the validated Params above (the base class assigns it)

    def __init__(self, params: Params, sizes: ModelSizes):
        super().__init__(params, sizes)
        self.step = InteractionStep(sizes.latent, sizes.mlp_hidden, sizes.mlp_hidden_layers, params.edge_block)

    def forward(self, node_latent: Tensor, edge_latent: Tensor, graph: Graph) -> tuple[Tensor, Tensor]:
        order = edge_order(self.step, edge_latent, graph) if self.params.edge_block == "fused" else None
        for k in range(self.params.message_passing_steps):
            if k and graph.exchange is not None:  # a domain-decomposed step: the halo's latents from their owners
                node_latent = graph.exchange(node_latent)
            node_latent, edge_latent = self.step(node_latent, edge_latent, graph.senders, graph.receivers, order)
        return node_latent, edge_latent
