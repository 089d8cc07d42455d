"""One interaction-network step applied M times with the same weights."""

from __future__ import annotations

from torch import Tensor

from gns_framework.contracts import Graph, ModelSizes, Processor

from .._kernels.edge_block import edge_order
from .interaction_network import InteractionNetwork, InteractionStep


class SharedInteractionNetwork(Processor):
    """The reference step (see ``interaction_network``) repeated M times, weights shared.

    M times fewer processor parameters than the unshared network for the same
    receptive field (M hops); the cost per step is unchanged.
    """

    name = "shared_interaction_network"
    node_module_names = ("step.node_mlp",)
    hops_param = "message_passing_steps"
    exchanges_latents = True

    Params = InteractionNetwork.Params  # M (here the times the one step is applied) and the edge block
    params: InteractionNetwork.Params  # the validated Params (the base class assigns it)

    def __init__(self, params: InteractionNetwork.Params, sizes: ModelSizes):
        super().__init__(params, sizes)
        self.step = InteractionStep(sizes.latent, sizes.mlp_hidden, sizes.mlp_hidden_layers, params.edge_block)

    def forward(self, node_latent: Tensor, edge_latent: Tensor, graph: Graph) -> tuple[Tensor, Tensor]:
        order = edge_order(self.step, edge_latent, graph) if self.params.edge_block == "fused" else None
        for k in range(self.params.message_passing_steps):
            if k and graph.exchange is not None:  # a domain-decomposed step: the halo's latents from their owners
                node_latent = graph.exchange(node_latent)
            node_latent, edge_latent = self.step(node_latent, edge_latent, graph.senders, graph.receivers, order)
        return node_latent, edge_latent
