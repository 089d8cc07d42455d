"""The reference encoder: independent MLP + LayerNorm on node and edge features."""

from __future__ import annotations

import torch
from torch import Tensor
from torch.utils.checkpoint import checkpoint

from gns_framework.api import NormedMLP, recompute_activations
from gns_framework.contracts import ComponentParams, Encoder, ModelSizes


class MLPEncoder(Encoder):
    """Node features (N, node_in) -> (N, L) and edge features (E, edge_in) -> (E, L).

    With :func:`~gns_framework.runtime.activation_memory.recompute_activations` the edge MLP
    is checkpointed: its backward reruns it from the (E, d + 1) features instead of
    keeping its hidden layers, LayerNorm input and output, ~2 KB per edge at the
    paper's sizes in float32 (the same values: the rerun is the same computation).
    """

    name = "mlp"
    node_module_names = ("node_mlp",)

    def __init__(self, params: ComponentParams, sizes: ModelSizes):
        super().__init__(params, sizes)
        self.node_mlp = NormedMLP(sizes.node_in, sizes.mlp_hidden, sizes.mlp_hidden_layers, sizes.latent)
        self.edge_mlp = NormedMLP(sizes.edge_in, sizes.mlp_hidden, sizes.mlp_hidden_layers, sizes.latent)

    def forward(self, node_features: Tensor, edge_features: Tensor) -> tuple[Tensor, Tensor]:
        if recompute_activations() and torch.is_grad_enabled():
            return self.node_mlp(node_features), checkpoint(self.edge_mlp, edge_features, use_reentrant=False)
        return self.node_mlp(node_features), self.edge_mlp(edge_features)
