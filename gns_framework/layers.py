"""The MLP every built-in encoder, processor and decoder is made of, for plugins to build theirs the same way.

Part of the plugin API (docs/plugin-authors.md, section 9): a plugin's component
builds its MLPs from these instead of a copy, so its layers are laid out, named and
initialised like the built-ins' (``linears.<i>``, then ``norm``).

The built-in blocks follow the reference model (Sanchez-Gonzalez et al. 2020): the
encoder and every processor block are a :class:`NormedMLP` (the latents stay
LayerNorm-scaled), a processor adds its blocks' outputs to its inputs (residuals),
and the decoder is a plain :class:`MLP` (its output is a normalised prediction).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn


class MLP(nn.Module):
    """``Linear, ReLU, ..., Linear`` with ``hidden_layers`` hidden layers (the reference's ``build_mlp``).

    Sizes come from :class:`~gns_framework.contracts.ModelSizes`:
    ``MLP(in_size, sizes.mlp_hidden, sizes.mlp_hidden_layers, sizes.latent)``.
    Shapes: (..., in_size) -> (..., out_size).
    """

    def __init__(self, in_size: int, hidden_size: int, hidden_layers: int, out_size: int):
        super().__init__()
        sizes = [in_size] + [hidden_size] * hidden_layers + [out_size]
        self.linears = nn.ModuleList(nn.Linear(sizes[k], sizes[k + 1]) for k in range(len(sizes) - 1))

    def forward(self, x: Tensor) -> Tensor:
        return self.rest(self.linears[0](x))

    def rest(self, first_layer_output: Tensor) -> Tensor:
        """Apply everything after the first Linear (its output given), for callers that split it."""
        x = first_layer_output
        for linear in self.linears[1:]:
            x = linear(torch.relu(x))
        return x


class NormedMLP(nn.Module):
    """:class:`MLP` followed by LayerNorm over its ``out_size`` outputs (encoder and processor blocks).

    Shapes: (..., in_size) -> (..., out_size).
    """

    def __init__(self, in_size: int, hidden_size: int, hidden_layers: int, out_size: int):
        super().__init__()
        self.mlp = MLP(in_size, hidden_size, hidden_layers, out_size)
        self.norm = nn.LayerNorm(out_size)

    def forward(self, x: Tensor) -> Tensor:
        return self.norm(self.mlp(x))
