"""The encoder contract: node and edge features to latents."""

from __future__ import annotations

from abc import ABC, abstractmethod

from torch import Tensor

from .learned_part import LearnedPart


class Encoder(LearnedPart, ABC):
    """Maps node and edge features to latents."""

    @abstractmethod
    def forward(self, node_features: Tensor, edge_features: Tensor) -> tuple[Tensor, Tensor]:
        """(N, node_in), (E, edge_in) -> node latent (N, L), edge latent (E, L)."""
