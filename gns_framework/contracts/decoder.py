"""The decoder contract: node latents to the normalised prediction."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import ClassVar

from torch import Tensor, nn

from .params import ComponentParams, Params
from .setup import ModelSizes


class Decoder(nn.Module, ABC):
    """Maps node latents to the normalised quantity the integrator consumes."""

    name: ClassVar[str]
    Params: ClassVar[type[Params]] = Params

    def __init__(self, params: ComponentParams, sizes: ModelSizes):
        super().__init__()
        self.params = params

    @abstractmethod
    def forward(self, node_latent: Tensor) -> Tensor:
        """(N, L) -> (N, sizes.output)."""
