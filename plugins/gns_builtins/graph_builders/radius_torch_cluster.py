"""The reference graph found by torch-cluster's radius search (optional dependency)."""

from __future__ import annotations

import importlib

import torch
from pydantic import Field
from torch import Tensor

from gns_framework.api import PluginError
from gns_framework.contracts import ComponentParams, Graph, GraphBuilder, ModelSetup

from .._kernels.cell_list import squared_distance

_SEARCH_MARGIN = 1 + 2**-10
"""torch-cluster compares in its own rounding; search slightly wider, then filter exactly."""


class TorchClusterRadiusGraphBuilder(GraphBuilder):
    """Same edges as ``radius`` (strict ``d^2 < R^2``, self-edges), searched by torch-cluster.

    Registered whether or not torch-cluster is installed, so recipes validate and
    ``gns plugins`` lists it on every machine; building it without torch-cluster
    raises an error saying what to install. torch-cluster caps neighbours per
    particle; whenever a particle reaches the cap the search is repeated with a
    doubled cap, so no neighbour is ever dropped. Candidates are then filtered
    with the same arithmetic as ``radius``, so both give the same edge set.
    Edges are sorted by (receiver, sender).
    """

    name = "radius_torch_cluster"
    joins_within_radius = True
    optional_modules = ("torch_cluster",)
    """Modules this component needs that the project does not install by default (``gns check`` looks for them)."""

    class Params(ComponentParams):
        initial_max_neighbors: int = Field(
            64, ge=1, description="first neighbour cap; doubled until no particle reaches it"
        )

    params: Params  # the validated Params above (the base class assigns it)

    def __init__(self, params: Params, setup: ModelSetup):
        super().__init__(params, setup)
        try:
            self._torch_cluster = importlib.import_module("torch_cluster")
        except ImportError as exc:
            raise PluginError(
                f"graph builder {self.name!r} needs torch-cluster, which is not importable ({exc}); "
                "install it (pip install torch-cluster, matching your torch and CUDA versions) "
                "or use graph_builder: {name: radius}, the pure-torch cell list with the same edges"
            ) from None

    def build(self, position: Tensor, batch: Tensor, num_examples: int) -> Graph:
        radius = self.setup.connectivity_radius
        cap = self.params.initial_max_neighbors
        n = position.shape[0]
        while True:
            receivers, senders = self._torch_cluster.radius(
                position, position, radius * _SEARCH_MARGIN, batch, batch, max_num_neighbors=cap
            )
            per_receiver = torch.bincount(receivers, minlength=n)
            if n == 0 or int(per_receiver.max()) < cap:
                break
            cap *= 2
        r2 = torch.tensor(radius * radius, dtype=position.dtype, device=position.device)
        keep = squared_distance(position[receivers], position[senders]) < r2
        senders, receivers = senders[keep], receivers[keep]
        order = torch.argsort(receivers * n + senders)
        senders, receivers = senders[order], receivers[order]
        return Graph(senders, receivers, position[senders] - position[receivers], n, receivers_sorted=True)
