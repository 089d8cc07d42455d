"""The reference encoder: independent MLP + LayerNorm on node and edge features."""

from __future__ import annotations

from torch import Tensor

from gns_framework.contracts import Encoder, ModelSizes, Params

from ..layers import NormedMLP


class MLPEncoder(Encoder):
    """Node features (N, node_in) -> (N, L) and edge features (E, edge_in) -> (E, L)."""

    name = "mlp"

    class Params(Params):
        pass

    def __init__(self, params: Params, sizes: ModelSizes):
        super().__init__(params, sizes)
        self.node_mlp = NormedMLP(sizes.node_in, sizes.mlp_hidden, sizes.mlp_hidden_layers, sizes.latent)
        self.edge_mlp = NormedMLP(sizes.edge_in, sizes.mlp_hidden, sizes.mlp_hidden_layers, sizes.latent)

    def forward(self, node_features: Tensor, edge_features: Tensor) -> tuple[Tensor, Tensor]:
        return self.node_mlp(node_features), self.edge_mlp(edge_features)
