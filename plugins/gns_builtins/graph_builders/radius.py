"""The reference graph: all pairs closer than the connectivity radius, self-edges included."""

from __future__ import annotations

from functools import partial

from pydantic import Field
from torch import Tensor

from gns_framework.contracts import ComponentParams, Graph, GraphBuilder, ModelSetup

from .._kernels.cell_list import radius_pairs
from .._kernels.verlet_list import VerletList


class RadiusGraphBuilder(GraphBuilder):
    """Edges between particles of one example closer than R (strict ``<``), self-edges included.

    No neighbour cap: unlike torch_cluster's ``max_num_neighbors`` (which silently keeps
    an implementation-defined subset), every neighbour is kept, however dense the scene.
    Pure torch cell list, O(N). Edges are sorted by (receiver, sender). ``skin`` > 0:
    the same graph, searched less often in a rollout (a Verlet list, ``_kernels/verlet_list.py``).
    """

    name = "radius"
    joins_within_radius = True

    class Params(ComponentParams):
        skin: float = Field(
            0.0,
            ge=0.0,
            description="Verlet-list skin in connectivity radii (0: search every frame); the graph is the same",
        )

    def __init__(self, params: Params, setup: ModelSetup):
        super().__init__(params, setup)
        radius = setup.connectivity_radius
        self.verlet = VerletList(radius, params.skin * radius) if params.skin > 0 else None

    def build(self, position: Tensor, batch: Tensor, num_examples: int) -> Graph:
        search = self.verlet.pairs if self.verlet else partial(radius_pairs, radius=self.setup.connectivity_radius)
        senders, receivers = search(position, batch)
        return Graph(senders, receivers, position[senders] - position[receivers], len(position), receivers_sorted=True)
