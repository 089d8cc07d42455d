"""The graph-builder contract: edges between particles closer than the connectivity radius."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import ClassVar

from torch import Tensor

from .graph import Graph
from .params import ComponentParams, Params
from .setup import ModelSetup


class GraphBuilder(ABC):
    """Finds the edges of a batch of particles."""

    name: ClassVar[str]
    Params: ClassVar[type[Params]] = Params
    supports_periodic: ClassVar[bool] = False
    """Whether it connects particles across periodic boundaries (minimum image)."""
    joins_within_radius: ClassVar[bool] = False
    """Whether two particles are joined by their own positions alone, when closer than the connectivity radius (not
    k nearest): what a domain-decomposed rollout (:mod:`gns_framework.decomposition`) needs of a builder."""
    optional_modules: ClassVar[tuple[str, ...]] = ()
    """Importable modules this component needs beyond the project's own requirements (``gns check`` finds the
    missing ones); any component class may declare it."""

    def __init__(self, params: ComponentParams, scene: ModelSetup):
        self.params = params
        self.scene = scene

    @abstractmethod
    def build(self, position: Tensor, batch: Tensor, num_examples: int) -> Graph:
        """Connect particles of the same example.

        Args:
            position: (N, d) current positions.
            batch: (N,) int64 example index of every particle, non-decreasing.
            num_examples: B.
        """
