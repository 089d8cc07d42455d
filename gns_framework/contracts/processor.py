"""The processor contract: message passing on the latents."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import ClassVar

from torch import Tensor, nn

from .graph import Graph
from .params import ComponentParams, Params
from .setup import ModelSizes


class Processor(nn.Module, ABC):
    """Message passing on the latent graph."""

    name: ClassVar[str]
    Params: ClassVar[type[Params]] = Params

    def __init__(self, params: ComponentParams, sizes: ModelSizes):
        super().__init__()
        self.params = params

    @abstractmethod
    def forward(self, node_latent: Tensor, edge_latent: Tensor, graph: Graph) -> tuple[Tensor, Tensor]:
        """(N, L), (E, L) -> updated (N, L), (E, L)."""
