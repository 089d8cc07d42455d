"""The reference graph in buffers of fixed size: no wait for the device per build, so a step can be captured."""

from __future__ import annotations

from collections.abc import Hashable, Iterator
from contextlib import contextmanager

import torch
from pydantic import Field
from torch import Tensor

from gns_framework.api import avoids_read_backs
from gns_framework.contracts import ComponentParams, Graph, GraphBuilder, ModelSetup

from .._kernels.fixed_capacity import FixedCapacityRadius

INT32_NODES = 2**31
"""Graphs of at most this many nodes (particles and the sink) get int32 indices on accelerators."""


class FixedCapacityRadiusGraphBuilder(GraphBuilder):
    """The edges of ``radius`` (same pairs, same order), then padding up to a capacity fixed per scene.

    ``radius`` learns its edge count from the device at every build; on a GPU that wait
    keeps the host from running ahead and a rollout step from being captured as one
    CUDA graph. Here the buffers are sized on a scene's first build (``capacity`` times
    what it needed) and every later build is the same operations on the same shapes.
    On accelerators the indices are int32 (half the bytes every gather of a step reads).
    Padding edges join a sink node N after the particles (``Graph.num_nodes`` = N + 1),
    which the learned simulator gives the last particle's features and drops after
    the processor, so no particle receives a padding message.

    A build that needs more than the buffers hold is incomplete: ``gns rollout`` (and
    every command that rolls out one scene) calls :meth:`overflowed` every few steps and
    redoes those steps with grown buffers; every other caller (training, batched and
    partitioned rollouts, inverse problems) has each build checked at once, one read-back.
    """

    name = "radius_fixed_capacity"
    joins_within_radius = True
    fixed_capacity = True

    class Params(ComponentParams):
        capacity: float = Field(
            1.25,
            ge=1.0,
            le=16.0,
            description="buffer sizes as a multiple of the most a scene has needed (edges, candidates, grid cells)",
        )

    def __init__(self, params: Params, setup: ModelSetup):
        super().__init__(params, setup)
        self.search = FixedCapacityRadius(setup.connectivity_radius, params.capacity)
        self._kept: dict[Hashable, FixedCapacityRadius] = {}

    def build(self, position: Tensor, batch: Tensor, num_examples: int) -> Graph:
        n = len(position)
        if n == 0:
            empty = torch.zeros(0, dtype=torch.long, device=position.device)
            return Graph(empty, empty, position[:0], 0, receivers_sorted=True)
        senders, receivers = self.search.pairs(position, batch, num_examples, check_now=not self.checks_deferred)
        if avoids_read_backs(position.device) and n + 1 <= INT32_NODES:
            # On a GPU every message-passing step gathers rows by these: int32 halves that index traffic.
            senders, receivers = senders.to(torch.int32), receivers.to(torch.int32)
        # The sink node N takes the last particle's features and position: padding edges have zero displacement.
        node_particle = torch.arange(n + 1, device=position.device).clamp(max=n - 1)
        on_nodes = position[node_particle]
        displacement = on_nodes[senders] - on_nodes[receivers]
        return Graph(senders, receivers, displacement, n + 1, receivers_sorted=True, node_particle=node_particle)

    def overflowed(self) -> bool:
        return self.search.overflowed()

    @contextmanager
    def buffers(self, key: Hashable) -> Iterator[None]:
        """Builds within search with the buffers kept for ``key`` (made on its first build), then the previous."""
        outside = self.search
        self.search = self._kept.setdefault(key, FixedCapacityRadius(outside.radius, outside.growth))
        try:
            yield
        finally:
            self.search = outside
