"""The processor contract: message passing on the latents."""

from __future__ import annotations

from abc import ABC, abstractmethod
from torch import Tensor

from .graph import Graph
from .learned_part import LearnedPart


class Processor(LearnedPart, ABC):
    """Message passing on the latent graph."""

    @abstractmethod
    def forward(self, node_latent: Tensor, edge_latent: Tensor, graph: Graph) -> tuple[Tensor, Tensor]:
        """(N, L), (E, L) -> updated (N, L), (E, L)."""
