"""The processor contract: message passing on the latents."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import ClassVar

from torch import Tensor

from .graph import Graph
from .learned_part import LearnedPart


class Processor(LearnedPart, ABC):
    """Message passing on the latent graph."""

    hops_param: ClassVar[str | None] = None
    """The parameter that says how many edges away a particle's output can depend on (M message-passing steps);
    None when it reaches farther (a grid over the scene). A domain-decomposed rollout needs one."""
    exchanges_latents: ClassVar[bool] = False
    """Whether ``forward`` passes the node latents through ``graph.exchange`` (when set) between its message-passing
    steps, so a domain decomposition can use a halo one radius deep (:mod:`gns_framework.decomposition.halo`)."""

    @abstractmethod
    def forward(self, node_latent: Tensor, edge_latent: Tensor, graph: Graph) -> tuple[Tensor, Tensor]:
        """(N, L), (E, L) -> updated (N, L), (E, L)."""
