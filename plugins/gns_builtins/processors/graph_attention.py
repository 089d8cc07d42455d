"""Graph-attention processor built on PyG's GATv2 operator (Brody et al. 2022)."""

from __future__ import annotations

import torch
from pydantic import Field
from torch import Tensor, nn

from gns_framework.api import NormedMLP
from gns_framework.contracts import ComponentParams, Graph, ModelSizes, Processor


class AttentionStep(nn.Module):
    """One step: attention-weighted messages, then an MLP, with residuals.

    ``GATv2Conv`` scores every edge from the receiver, sender and edge latents
    (``a^T LeakyReLU(W [x_i, x_j, e_ij])``), softmax-normalises the scores over
    each receiver's incoming edges and sums the weighted sender messages. The
    heads' outputs are concatenated back to L. PyG's operator never updates the edge
    attributes; here the edge latent is then updated from its endpoints, as in the
    interaction network, so that later steps attend with it.

    The last step of a stack updates no edges: nothing reads its edge latent (the
    decoder reads nodes only), so an edge MLP there would be a parameter without a
    gradient, which DistributedDataParallel refuses. It has no ``edge_mlp``.

    Shapes: x (N, L), e (E, L) -> same.
    """

    def __init__(self, latent: int, hidden: int, hidden_layers: int, heads: int, updates_edges: bool):
        super().__init__()
        # Imported here: torch_geometric is slow to import and only this processor needs it.
        from torch_geometric.nn import GATv2Conv

        # Our graphs already contain self-edges, so GATv2Conv must not add more.
        self.attention = GATv2Conv(latent, latent // heads, heads=heads, edge_dim=latent, add_self_loops=False)
        self.node_mlp = NormedMLP(2 * latent, hidden, hidden_layers, latent)
        self.edge_mlp = NormedMLP(3 * latent, hidden, hidden_layers, latent) if updates_edges else None
        if self.edge_mlp is None:
            self.register_load_state_dict_pre_hook(_drop_untrained_edge_mlp)

    def forward(self, x: Tensor, e: Tensor, senders: Tensor, receivers: Tensor) -> tuple[Tensor, Tensor]:
        # PyG's edge_index is (source, target): messages flow sender -> receiver.
        aggregate = self.attention(x, torch.stack([senders, receivers]), e)
        x = x + self.node_mlp(torch.cat([x, aggregate], dim=-1))
        if self.edge_mlp is not None:
            e = e + self.edge_mlp(torch.cat([e, x[receivers], x[senders]], dim=-1))
        return x, e


def _drop_untrained_edge_mlp(module, state_dict, prefix, *args) -> None:
    """Checkpoints written while the last step still had an edge MLP hold its weights at their initial
    values (no gradient ever reached them): drop them, so that those checkpoints load."""
    for key in [k for k in state_dict if k.startswith(f"{prefix}edge_mlp.")]:
        del state_dict[key]


class GraphAttentionProcessor(Processor):
    """M unshared GATv2 attention steps with residuals on nodes, and on edges in every step but the last."""

    name = "graph_attention"
    hops_param = "message_passing_steps"

    class Params(ComponentParams):
        message_passing_steps: int = Field(10, ge=1, description="M, number of unshared steps")
        heads: int = Field(4, ge=1, description="attention heads; must divide the latent size")

    def __init__(self, params: Params, sizes: ModelSizes):
        super().__init__(params, sizes)
        if sizes.latent % params.heads:
            raise ValueError(f"graph_attention: heads ({params.heads}) must divide latent_size ({sizes.latent})")
        self.steps = nn.ModuleList(
            AttentionStep(
                sizes.latent,
                sizes.mlp_hidden,
                sizes.mlp_hidden_layers,
                params.heads,
                updates_edges=i < params.message_passing_steps - 1,
            )
            for i in range(params.message_passing_steps)
        )

    def forward(self, node_latent: Tensor, edge_latent: Tensor, graph: Graph) -> tuple[Tensor, Tensor]:
        for step in self.steps:
            node_latent, edge_latent = step(node_latent, edge_latent, graph.senders, graph.receivers)
        return node_latent, edge_latent
