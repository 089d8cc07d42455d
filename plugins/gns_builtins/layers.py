"""Building blocks shared by the built-in encoder, processor and decoder."""

from __future__ import annotations

import torch
from torch import Tensor, nn


class MLP(nn.Module):
    """``Linear, ReLU, ..., Linear`` with ``hidden_layers`` hidden layers (the reference's ``build_mlp``).

    Shapes: (..., in_size) -> (..., out_size).
    """

    def __init__(self, in_size: int, hidden_size: int, hidden_layers: int, out_size: int):
        super().__init__()
        sizes = [in_size] + [hidden_size] * hidden_layers + [out_size]
        self.linears = nn.ModuleList(nn.Linear(a, b) for a, b in zip(sizes[:-1], sizes[1:]))

    def forward(self, x: Tensor) -> Tensor:
        return self.rest(self.linears[0](x))

    def rest(self, first_layer_output: Tensor) -> Tensor:
        """Apply everything after the first Linear (its output given), for callers that split it."""
        x = first_layer_output
        for linear in self.linears[1:]:
            x = linear(torch.relu(x))
        return x


class NormedMLP(nn.Module):
    """MLP followed by LayerNorm (encoder and processor blocks)."""

    def __init__(self, in_size: int, hidden_size: int, hidden_layers: int, out_size: int):
        super().__init__()
        self.mlp = MLP(in_size, hidden_size, hidden_layers, out_size)
        self.norm = nn.LayerNorm(out_size)

    def forward(self, x: Tensor) -> Tensor:
        return self.norm(self.mlp(x))
