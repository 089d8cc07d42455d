"""The graph-builder contract: edges between particles closer than the connectivity radius."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Hashable, Iterator
from contextlib import contextmanager
from typing import Any, ClassVar

from torch import Tensor

from ..moved import renamed_attribute, renamed_keywords
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
    fixed_capacity: ClassVar[bool] = False
    """Whether it builds into buffers of fixed size without waiting for the device: a rollout then calls
    :meth:`overflowed` every few steps instead of never."""
    checks_deferred: bool = False
    """Set by a caller that calls :meth:`overflowed` itself every few steps and redoes the steps since (a rollout);
    otherwise a fixed-capacity builder checks each build at once."""
    optional_modules: ClassVar[tuple[str, ...]] = ()
    """Importable modules this component needs beyond the project's own requirements (``gns check`` finds the
    missing ones); any component class may declare it."""

    scene = renamed_attribute("scene", "setup")  # its name until 0.2

    @renamed_keywords(scene="setup")
    def __init__(self, params: ComponentParams, setup: ModelSetup):
        self.params = params
        self.setup = setup

    def __init_subclass__(cls, **kwargs: Any):
        # A subclass's own __init__ takes ``scene=`` (the keyword's name until 0.2) too, unless it names it itself.
        super().__init_subclass__(**kwargs)
        if "__init__" in cls.__dict__:
            cls.__init__ = renamed_keywords(scene="setup")(cls.__dict__["__init__"])  # type: ignore[method-assign]

    @abstractmethod
    def build(self, position: Tensor, batch: Tensor, num_examples: int) -> Graph:
        """Connect particles of the same example. A particle whose position is not finite joins no edge (a batch
        padded to a capacity class carries such rows: :mod:`gns_framework.model.capacity_classes`).

        Args:
            position: (N, d) current positions.
            batch: (N,) int64 example index of every particle, non-decreasing.
            num_examples: B.
        """

    def overflowed(self) -> bool:
        """Whether a graph built since the last call was incomplete because a buffer of fixed size was too small.

        A builder that writes its edges into buffers of fixed size, so that the host never waits
        for the device (``radius_fixed_capacity``), learns this on the device; here it reads it
        back (one wait), grows the buffers and forgets it, and the caller redoes the steps since
        its last call. A rollout calls it every few steps. Builders of exact size never overflow.
        """
        return False

    @contextmanager
    def buffers(self, key: Hashable) -> Iterator[None]:
        """Builds within use the buffers of fixed size kept for ``key``.

        A batched rollout keeps one captured step per capacity class; each replays the
        buffers it was captured with and must be checked by :meth:`overflowed` against
        those, not against another class's. Builders of exact size have no buffers.
        """
        yield
