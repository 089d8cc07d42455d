"""The decoder contract: node latents to the normalised prediction."""

from __future__ import annotations

from abc import ABC, abstractmethod

from torch import Tensor

from .learned_part import LearnedPart


class Decoder(LearnedPart, ABC):
    """Maps node latents to the normalised quantity the integrator consumes."""

    node_module_names = ("",)
    """A decoder acts on node latents alone: the whole of it is the node side."""

    @abstractmethod
    def forward(self, node_latent: Tensor) -> Tensor:
        """(N, L) -> (N, sizes.output)."""
