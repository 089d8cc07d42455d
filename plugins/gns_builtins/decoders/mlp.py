"""The reference decoder: an MLP without LayerNorm."""

from __future__ import annotations

from torch import Tensor

from gns_framework.api import MLP
from gns_framework.contracts import ComponentParams, Decoder, ModelSizes


class MLPDecoder(Decoder):
    """Node latent (N, L) -> normalised prediction (N, d)."""

    name = "mlp"

    def __init__(self, params: ComponentParams, sizes: ModelSizes):
        super().__init__(params, sizes)
        self.mlp = MLP(sizes.latent, sizes.mlp_hidden, sizes.mlp_hidden_layers, sizes.output)

    def forward(self, node_latent: Tensor) -> Tensor:
        return self.mlp(node_latent)
