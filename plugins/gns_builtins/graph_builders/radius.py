"""The reference graph: all pairs closer than the connectivity radius, self-edges included."""

from __future__ import annotations

from torch import Tensor

from gns_framework.contracts import Graph, GraphBuilder, ComponentParams

from .._kernels.cell_list import radius_pairs


class RadiusGraphBuilder(GraphBuilder):
    """Edges between particles of one example closer than R (strict ``<``), self-edges included.

    No neighbour cap: unlike torch_cluster's ``max_num_neighbors`` (which silently keeps
    an implementation-defined subset), every neighbour is kept, however dense the scene.
    Pure torch cell list, O(N). Edges are sorted by (receiver, sender).
    """

    name = "radius"

    class Params(ComponentParams):
        pass

    def build(self, position: Tensor, batch: Tensor, num_examples: int) -> Graph:
        senders, receivers = radius_pairs(position, batch, self.scene.connectivity_radius)
        return Graph(
            senders=senders,
            receivers=receivers,
            displacement=position[senders] - position[receivers],
            num_nodes=position.shape[0],
        )
