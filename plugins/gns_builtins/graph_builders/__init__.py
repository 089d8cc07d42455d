"""Built-in graph builders."""

from gns_framework.api import hookimpl

from .knn import KnnGraphBuilder
from .no_edges import NoEdgesGraphBuilder
from .periodic_radius import PeriodicRadiusGraphBuilder
from .radius import RadiusGraphBuilder
from .radius_fixed_capacity import FixedCapacityRadiusGraphBuilder
from .radius_torch_cluster import TorchClusterRadiusGraphBuilder


@hookimpl
def gns_graph_builders():
    return [
        RadiusGraphBuilder,
        FixedCapacityRadiusGraphBuilder,
        TorchClusterRadiusGraphBuilder,
        KnnGraphBuilder,
        PeriodicRadiusGraphBuilder,
        NoEdgesGraphBuilder,
    ]
