"""The reference graph: all pairs closer than the connectivity radius, self-edges included."""

from __future__ import annotations

from pydantic import Field
from torch import Tensor

from gns_framework.contracts import ComponentParams, Graph, GraphBuilder, ModelSetup

from .._kernels.cell_list import radius_pairs
from .._kernels.verlet_list import VerletList


class RadiusGraphBuilder(GraphBuilder):
    """Edges between particles of one example closer than R (strict ``<``), self-edges included.

    No neighbour cap: unlike torch_cluster's ``max_num_neighbors`` (which silently keeps
    an implementation-defined subset), every neighbour is kept, however dense the scene.
    Pure torch cell list, O(N). Edges are sorted by (receiver, sender).

    With ``skin`` > 0 the search keeps its pairs closer than R (1 + skin) and later
    frames of the same particles only filter them, until some particle has moved
    about half the skin (a Verlet list, ``_kernels/verlet_list.py``): the same graph,
    searched less often in a rollout. Training windows change every step, so there
    it searches every step.
    """

    name = "radius"

    class Params(ComponentParams):
        skin: float = Field(
            0.0,
            ge=0.0,
            description="Verlet-list skin in connectivity radii (0: search every frame); the graph is the same",
        )

    def __init__(self, params: Params, scene: ModelSetup):
        super().__init__(params, scene)
        radius, skin = scene.connectivity_radius, params.skin
        self.verlet = VerletList(radius, skin * radius) if skin > 0 else None

    def build(self, position: Tensor, batch: Tensor, num_examples: int) -> Graph:
        if self.verlet is not None:
            senders, receivers = self.verlet.pairs(position, batch)
        else:
            senders, receivers = radius_pairs(position, batch, self.scene.connectivity_radius)
        return Graph(
            senders=senders,
            receivers=receivers,
            displacement=position[senders] - position[receivers],
            num_nodes=position.shape[0],
        )
