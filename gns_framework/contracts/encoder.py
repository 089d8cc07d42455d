"""The encoder contract: node and edge features to latents."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import ClassVar

from torch import Tensor, nn

from .params import ComponentParams, Params
from .setup import ModelSizes


class Encoder(nn.Module, ABC):
    """Maps node and edge features to latents."""

    name: ClassVar[str]
    Params: ClassVar[type[Params]] = Params

    def __init__(self, params: ComponentParams, sizes: ModelSizes):
        super().__init__()
        self.params = params

    @abstractmethod
    def forward(self, node_features: Tensor, edge_features: Tensor) -> tuple[Tensor, Tensor]:
        """(N, node_in), (E, edge_in) -> node latent (N, L), edge latent (E, L)."""
